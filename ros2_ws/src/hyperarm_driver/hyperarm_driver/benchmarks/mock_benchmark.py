"""mock_benchmark: CPU cost of the mock driver and of its simulation core.

1. Process: starts the installed ``mock_driver`` (a separate process, private ROS domain)
   at ``--rate`` Hz and measures, over ``--duration`` s of wall time after ``--warmup`` s,
   the CPU time it used (user + system, all threads, from /proc/<pid>/stat) and the rate of
   ``joint_states`` a subscriber in this process received: once with the arm at rest, once
   with every joint moving (goals streamed at 50 Hz). Target: 200 Hz with 10 joints under
   25 % of one core.
2. Core: mean wall time of one ``JointSim.step`` (no ROS), free motion and pressing on the
   peg (contacts solved).

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
    from sensor_msgs.msg import JointState

    from hyperarm_description import contract
    from hyperarm_description.model import load_description
    from hyperarm_description.qos import qos_for

    domain = random.randint(150, 229)
    exe = Path(get_package_prefix("hyperarm_driver")) / "lib" / "hyperarm_driver" / "mock_driver"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cmd = [str(exe), "--ros-args", "-p", f"rate:={rate}", "-p", f"variant:={variant}",
           "-p", f"sim_speed:={sim_speed}"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("mock_benchmark", namespace=contract.DEFAULT_NAMESPACE, context=ctx)
    count = [0, 0]   # messages, joints in the last one
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
        for phase in ("at rest", "moving"):
            if phase == "moving":
                moving.set()
            time.sleep(warmup)
            c0, n0, t0 = _cpu_seconds(proc.pid), count[0], time.monotonic()
            time.sleep(duration)
            c1, n1, t1 = _cpu_seconds(proc.pid), count[0], time.monotonic()
            out[phase] = {"cpu": (c1 - c0) / (t1 - t0), "rate": (n1 - n0) / (t1 - t0),
                          "joints": count[1]}
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
    return out


def bench_core(steps: int = 2000) -> dict:
    import dataclasses

    import numpy as np

    from hyperarm_description.model import load_description

    from ..mock.config import load_mock_config
    from ..mock.joint_sim import JointSim
    from ..mock.scenario import Scenario

    cfg = load_mock_config()
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0, seed=0))
    sim = JointSim(load_description(), cfg)
    sim.command([f"joint{i}" for i in range(1, 10)], [0.5] * 9)
    t = time.perf_counter()
    for _ in range(steps):
        sim.step(0.005)
    free = (time.perf_counter() - t) / steps
    # pressing the held block on the destination peg's top (contacts solved every step)
    sc = Scenario(sim)
    w = cfg.world
    half = w.block.size[2] / 2.0
    src, dst = w.peg("source"), w.peg("destination")
    sc.grip(1.3, seconds=0.5)
    sc.move_tool([*src.xy, w.table_height + src.height + half + 0.02], 1.5)
    sc.move_tool([*src.xy, w.table_height + half], 1.0)
    sc.grip(0.0, 0.6, seconds=0.5)
    sc.move_tool([*src.xy, w.table_height + src.height + half + 0.02], 1.0)
    sc.move_tool([dst.xy[0] + 0.006, dst.xy[1], w.table_height + dst.height + half + 0.02], 1.5)
    sc.move_tool([dst.xy[0] + 0.006, dst.xy[1], w.table_height + dst.height + half - 0.005], 1.5)
    if not np.any(sim.contact_force):
        raise SystemExit("mock_benchmark: the pressing scenario made no contact")
    t = time.perf_counter()
    for _ in range(steps):
        sim.step(0.005)
    pressing = (time.perf_counter() - t) / steps
    return {"free_us": free * 1e6, "pressing_us": pressing * 1e6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mock_benchmark", description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=200.0, help="joint_states rate, Hz")
    ap.add_argument("--duration", type=float, default=10.0, help="measured interval, s")
    ap.add_argument("--warmup", type=float, default=3.0, help="s before measuring")
    ap.add_argument("--variant", default="arm", choices=("arm", "rail_arm"))
    ap.add_argument("--sim-speed", type=float, default=0.0, help="mock's sim_speed")
    ap.add_argument("--skip-core", action="store_true", help="only the process benchmark")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    print(f"mock_benchmark: mock_driver {args.variant} at {args.rate:g} Hz, sim_speed "
          f"{args.sim_speed:g}, {args.duration:g} s measured after {args.warmup:g} s")
    results = bench_process(args.rate, args.duration, args.warmup, args.variant, args.sim_speed)
    ok = True
    for phase, r in results.items():
        met = r["cpu"] < TARGET_CPU
        ok &= met
        print(f"  {phase:8s}: {r['joints']} joints, joint_states received {r['rate']:.1f} /s, "
              f"mock_driver CPU {100 * r['cpu']:.1f} % of one core "
              f"(target < {100 * TARGET_CPU:.0f} %: {'met' if met else 'NOT met'})")
    if not args.skip_core:
        c = bench_core()
        print(f"  JointSim.step, free       {c['free_us']:.0f} µs")
        print(f"  JointSim.step, pressing   {c['pressing_us']:.0f} µs")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
