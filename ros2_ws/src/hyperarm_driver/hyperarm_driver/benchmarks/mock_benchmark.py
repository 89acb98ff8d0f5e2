"""mock_benchmark: CPU cost of the mock driver and of its simulation core.

1. Process: starts the installed ``mock_driver`` (a separate process, private ROS domain)
   at ``--rate`` Hz and measures, over ``--duration`` s of wall time after ``--warmup`` s,
   the CPU time it used (user + system, all threads, from /proc/<pid>/stat) and the rate of
   ``joint_states`` a subscriber in this process received: with the arm at rest, with
   every joint moving (goals streamed at 50 Hz), and (arm variant) with the held block
   pressed on the destination peg's top, misaligned (the pick and press replayed on
   ``joint_command`` from a scripted run of the core, the mock on a copy of the packaged
   work cell without repeatability noise). Target: 200 Hz with 10 joints under 25 % of one
   core.
2. Core: CPU time (this thread's) of one 5 ms step of the simulation core (no ROS), free
   motion, at rest and pressing on the peg, for both engines in one run: the hand-written
   contact solver (``JointSim``, what mock_driver runs today) and MuJoCo (``MujocoSim``,
   issue 23), as % of one core at 200 Hz.

    ros2 run hyperarm_driver mock_benchmark [--rate 200] [--duration 10] [--variant arm]
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

TARGET_CPU = 0.25


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_process(rate: float, duration: float, warmup: float, variant: str,
                  sim_speed: float) -> dict:
    """Two phases of ``duration`` s: the arm at rest, then every joint moving (sinusoidal
    position goals streamed at 50 Hz on joint_command, as a task node would)."""
    import math

    import rclpy
    from ament_index_python.packages import get_package_prefix
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    from hyperarm_description import contract
    from hyperarm_description.model import load_description
    from hyperarm_description.qos import qos_for

    domain = random.randint(150, 229)
    exe = Path(get_package_prefix("hyperarm_driver")) / "lib" / "hyperarm_driver" / "mock_driver"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    workcell = _quiet_workcell()
    cmd = [str(exe), "--ros-args", "-p", f"rate:={rate}", "-p", f"variant:={variant}",
           "-p", f"sim_speed:={sim_speed}", "-p", f"workcell_file:={workcell}"]
    press = _press_commands() if variant == "arm" and sim_speed == 0.0 else []
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("mock_benchmark", namespace=contract.DEFAULT_NAMESPACE, context=ctx)
    count = [0, 0]   # messages, joints in the last one
    work_cell: dict[str, str] = {}
    node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, lambda m: work_cell.update(
        {kv.key: kv.value for st in m.status if st.name.endswith("work_cell")
         for kv in st.values}), qos_for(contract.DIAGNOSTICS))
    node.create_subscription(JointState, contract.JOINT_STATES,
                             lambda m: count.__setitem__(slice(0, 2), [count[0] + 1, len(m.name)]),
                             qos_for(contract.JOINT_STATES))
    pub = node.create_publisher(JointState, contract.JOINT_COMMAND,
                                qos_for(contract.JOINT_COMMAND))
    names = [n for n in load_description(variant=variant).all_joint_names if n != "rail"]
    moving = threading.Event()

    def stream() -> None:
        if moving.is_set():
            t = time.monotonic()
            pub.publish(JointState(name=names, position=[
                0.3 * math.sin(0.7 * t + i) + (0.5 if n == "gripper" else 0.0)
                for i, n in enumerate(names)]))

    node.create_timer(0.02, stream)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    stop = threading.Event()
    spinner = threading.Thread(target=lambda: [ex.spin_once(timeout_sec=0.05)
                                               for _ in iter(stop.is_set, True)], daemon=True)
    spinner.start()
    out = {}
    try:
        deadline = time.monotonic() + 30.0
        while count[0] == 0:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit("mock_benchmark: mock_driver did not start publishing")
            time.sleep(0.05)
        for phase in ("at rest", "moving", "pressing")[:3 if press else 2]:
            if phase == "moving":
                moving.set()
            if phase == "pressing":
                moving.clear()
                _replay(pub, JointState, press)
            time.sleep(warmup)
            c0, n0, t0 = _cpu_seconds(proc.pid), count[0], time.monotonic()
            time.sleep(duration)
            c1, n1, t1 = _cpu_seconds(proc.pid), count[0], time.monotonic()
            out[phase] = {"cpu": (c1 - c0) / (t1 - t0), "rate": (n1 - n0) / (t1 - t0),
                          "joints": count[1]}
            if phase == "pressing":
                force = float(work_cell.get("contact_force_N", "0 0 0").split()[2])
                if work_cell.get("block_state") != "held" or force < 0.1:
                    raise SystemExit(f"mock_benchmark: the block is not pressed on the peg "
                                     f"({work_cell}): the pressing phase is void")
                out[phase]["force"] = force
    finally:
        stop.set()
        spinner.join(timeout=2.0)
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        os.unlink(workcell)
    return out


def _quiet_workcell() -> str:
    """A copy of the packaged work cell without repeatability noise (path of a temp file),
    so that the replayed press lands where it was scripted: misaligned on the peg's top."""
    import tempfile

    import yaml

    from ..mock.config import default_workcell_path

    data = yaml.safe_load(default_workcell_path().read_text(encoding="utf-8"))
    data["imperfections"]["repeatability"] = 0.0
    fd, path = tempfile.mkstemp(prefix="mock_benchmark_", suffix=".yaml")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        yaml.safe_dump(data, f)
    return path


def _scripted_press(sim) -> None:
    """Pick the block off the source peg and press it, 6 mm off the destination peg's axis,
    5 mm into the peg's top (position mode), with :class:`Scenario` on ``sim``."""
    from ..mock.scenario import Scenario

    sc = Scenario(sim)
    w = sim.cfg.world
    half = w.block.size[2] / 2.0
    src, dst = w.peg("source"), w.peg("destination")
    sc.grip(1.3, seconds=0.5)
    sc.move_tool([*src.xy, w.table_height + src.height + half + 0.02], 1.5)
    sc.move_tool([*src.xy, w.table_height + half], 1.0)
    sc.grip(0.0, 0.6, seconds=0.5)
    sc.move_tool([*src.xy, w.table_height + src.height + half + 0.02], 1.0)
    sc.move_tool([dst.xy[0] + 0.006, dst.xy[1], w.table_height + dst.height + half + 0.02], 1.5)
    sc.move_tool([dst.xy[0] + 0.006, dst.xy[1], w.table_height + dst.height + half - 0.005], 1.5)


def _press_commands() -> list[tuple[float, list[str], list[float], list[float]]]:
    """The joint commands (sim time s, names, positions, efforts) of :func:`_scripted_press`
    from the arm at zero, recorded on the core without noise."""
    import dataclasses

    from hyperarm_description.model import load_description

    from ..mock.config import load_mock_config
    from ..mock.joint_sim import JointSim

    cfg = load_mock_config()
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0))
    sim = JointSim(load_description(), cfg)
    out = []
    command = sim.command

    def record(names, positions=(), efforts=()):
        out.append((sim.time, list(names), [float(x) for x in positions],
                    [float(x) for x in efforts]))
        return command(names, positions, efforts)

    sim.command = record  # type: ignore[method-assign]
    _scripted_press(sim)
    if not sim.contact_force[2] > 0.1:
        raise SystemExit("mock_benchmark: the scripted press made no contact")
    return out


def _replay(pub, joint_state, commands) -> None:
    """Bring the arm to zero, then publish ``commands`` at their times (real time)."""
    arm = [f"joint{i}" for i in range(1, 10)]
    pub.publish(joint_state(name=arm + ["gripper"], position=[0.0] * 10))
    time.sleep(3.0)
    start = time.monotonic()
    for t, names, positions, efforts in commands:
        delay = start + t - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)
        pub.publish(joint_state(name=names, position=positions, effort=efforts))


def bench_core(steps: int = 2000, workcell: str | None = None, engine: str = "hand-written"
               ) -> dict:
    """CPU time (µs, this thread) of one 5 ms ``JointSim.step``: free motion (every arm
    joint moving to 0.5 rad), at rest (settled there), then the held block pressed on the
    destination peg's top; ``workcell``: another cell (e.g. with a pole); ``engine``:
    ``hand-written`` (JointSim) or ``mujoco`` (MujocoSim)."""
    import dataclasses

    import numpy as np

    from hyperarm_description.model import load_description

    from ..mock.config import load_mock_config
    from ..mock.joint_sim import JointSim
    from ..mock.joint_sim import JointSim as MujocoSim

    sim_class = MujocoSim if engine == "mujoco" else JointSim
    cfg = load_mock_config(workcell)
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0, seed=0))
    sim = sim_class(load_description(), cfg)
    sim.command([f"joint{i}" for i in range(1, 10)], [0.5] * 9)
    t = time.thread_time()
    for _ in range(steps):
        sim.step(0.005)
    free = (time.thread_time() - t) / steps
    t = time.thread_time()
    for _ in range(steps):
        sim.step(0.005)
    rest = (time.thread_time() - t) / steps
    sim = sim_class(load_description(), cfg)
    _scripted_press(sim)
    out = {"free_us": free * 1e6, "rest_us": rest * 1e6}
    if not np.any(sim.contact_force):
        out["pressing_void"] = f"the pressing scenario made no contact (block {sim.world.state.value})"
        return out
    t = time.thread_time()
    for _ in range(steps):
        sim.step(0.005)
    pressing = (time.thread_time() - t) / steps
    if not sim.contact_force[2] > 0.1:
        out["pressing_void"] = "the block left the peg's top while timed"
        return out
    out["pressing_us"] = pressing * 1e6
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mock_benchmark", description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=200.0, help="joint_states rate, Hz")
    ap.add_argument("--duration", type=float, default=10.0, help="measured interval, s")
    ap.add_argument("--warmup", type=float, default=3.0, help="s before measuring")
    ap.add_argument("--variant", default="arm", choices=("arm", "rail_arm"))
    ap.add_argument("--sim-speed", type=float, default=0.0, help="mock's sim_speed")
    ap.add_argument("--skip-core", action="store_true", help="only the process benchmark")
    ap.add_argument("--core-only", action="store_true",
                    help="only the core (JointSim.step), default cell and with a pole")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.core_only:
        _print_core()
        return 0
    print(f"mock_benchmark: mock_driver {args.variant} at {args.rate:g} Hz, sim_speed "
          f"{args.sim_speed:g}, {args.duration:g} s measured after {args.warmup:g} s")
    results = bench_process(args.rate, args.duration, args.warmup, args.variant, args.sim_speed)
    ok = True
    for phase, r in results.items():
        met = r["cpu"] < TARGET_CPU
        ok &= met
        extra = f", contact force {r['force']:.2f} N" if "force" in r else ""
        print(f"  {phase:8s}: {r['joints']} joints, joint_states received {r['rate']:.1f} /s, "
              f"mock_driver CPU {100 * r['cpu']:.1f} % of one core "
              f"(target < {100 * TARGET_CPU:.0f} %: {'met' if met else 'NOT met'}){extra}")
    if not args.skip_core:
        _print_core()
    return 0 if ok else 1


def _print_core() -> None:
    from ..mock.config import default_workcell_path

    pole = str(default_workcell_path().parent / "workcell_pole.yaml")
    for engine, cls in (("hand-written", "JointSim"), ("mujoco", "MujocoSim")):
        for label, cell in (("default cell", None), ("with a pole", pole)):
            c = bench_core(workcell=cell, engine=engine)

            def fig(key: str) -> str:     # 5 ms steps: % of one core at 200 Hz
                return f"{c[key]:.0f} µs ({c[key] / 50.0:.1f} %)"
            press = fig("pressing_us") if "pressing_us" in c else \
                f"void: {c['pressing_void']}"
            print(f"  {cls}.step (5 ms), {label}: free {fig('free_us')}, at rest "
                  f"{fig('rest_us')}, pressing {press}; % of one core at 200 Hz")


if __name__ == "__main__":
    sys.exit(main())
