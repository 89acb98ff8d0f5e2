"""force_benchmark: figures of the hybrid force controller (docs/benchmarks.md).

1. ``core``: compute time of one control cycle of the ROS-free core (law + wrench estimate,
   ``ForceController.step``), both outputs, over random states: thread CPU time (median,
   p90; what a loaded machine does not inflate) and wall time (median).
2. ``latency``: joint_states in -> joint_command out through ROS, the installed
   ``hybrid_force`` in its own process, driven ping-pong by a probe (one joint state, wait
   for the command computed from it: it carries the state's stamp), p50, p90, p99, for
   both triggers and both executors, and the floor: the same probe against an echo node
   (``force_echo``: copies joint_states to joint_command, no law). Included: the probe's
   publish, DDS, the node's executor, deserialisation, the cycle, the command's publish,
   DDS back and the probe's EventsExecutor up to its callback (perf_counter there).
   ``stale_timeout`` 1 s: the probe sends a state only every ~10 ms plus the answer.
3. ``outputs``: 'position' vs 'torque' on the mock (installed ``mock_driver`` +
   ``hybrid_force``): a 2 cm goal step on the position axes (overshoot, final error, hold
   drift), plotted to a PNG with ``--plot``.

Usage: force_benchmark [--cycles N] [--samples N] [--plot docs/force_step.png]
       [--only core|latency|outputs] (matplotlib for --plot: requirements-bench.txt)
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from hyperarm_description.model import load_description

from ..force.controller import ControllerConfig, ForceController
from ..force.law import HybridLaw
from hyperarm_ik.kinematics import Kinematics


def bench_core(cycles: int) -> dict:
    kin = Kinematics(load_description())
    rng = np.random.default_rng(0)
    out = {}
    for output in ("position", "torque"):
        ctl = ForceController(HybridLaw(kin), config=ControllerConfig(output=output))
        q = np.array([0.0, 0.5, 0.0, 0.6, 0.0, 0.5, 0.0, -1.0, 0.0])
        ctl.step(0.0, q, np.zeros(9), np.zeros(9))
        ctl.enable(True, 0.0)
        cpu, wall = [], []
        for i in range(cycles):
            qi = q + rng.normal(0.0, 0.01, 9)
            dq = rng.normal(0.0, 0.1, 9)
            effort = rng.normal(0.0, 0.5, 9)
            c0, w0 = time.thread_time(), time.perf_counter()
            ctl.step(0.01 * (i + 1), qi, dq, effort)
            cpu.append(time.thread_time() - c0)
            wall.append(time.perf_counter() - w0)
        c, w = np.array(cpu) * 1e3, np.array(wall) * 1e3
        out[output] = (float(np.median(c)), float(np.percentile(c, 90)), float(np.median(w)))
    return out


def _launch(exe: str, domain: int, params: dict, log: Path) -> subprocess.Popen:
    from ament_index_python.packages import get_package_prefix

    pkg = {"hybrid_force": "hyperarm_control", "mock_driver": "hyperarm_driver"}[exe]
    cmd = [str(Path(get_package_prefix(pkg)) / "lib" / pkg / exe), "--ros-args"]
    for k, v in params.items():
        cmd += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.Popen(cmd, stdout=open(log, "wb"), stderr=subprocess.STDOUT, env=env,
                            start_new_session=True)


def _wait(cond, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.005)


class _Ros:
    """A context, an executor thread and a probe on ``domain``."""

    def __init__(self, domain: int, driver: bool) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from .force_probe import ForceProbe

        os.environ["ROS_DOMAIN_ID"] = str(domain)
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.stop = threading.Event()
        self.probe = ForceProbe(self.ctx, self.ex, _wait, driver=driver)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.stop.is_set() and self.ctx.ok():
            self.ex.spin_once(timeout_sec=0.005)

    def close(self) -> None:
        import rclpy
        self.stop.set()
        self.probe.close()
        self.thread.join(2.0)
        self.probe.node.destroy_node()
        self.ex.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown(context=self.ctx)


def _stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(10.0)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)


class _LatencyProbe:
    """The latency benchmark's probe, on a fast path of its own: an EventsExecutor (wait and
    dispatch in C++), only a joint_states publisher, a joint_command subscription whose
    callback takes the arrival time (perf_counter) and wakes the waiting main thread, the
    enable client and a ``hold`` service. Nothing else is subscribed, so the probe's own
    receive path is as short as rclpy allows (its share is the echo figure's)."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.context import Context
        from sensor_msgs.msg import JointState
        from std_srvs.srv import SetBool, Trigger

        from hyperarm_description import contract
        from hyperarm_description.qos import qos_for
        from hyperarm_description.ros_main import make_executor

        os.environ["ROS_DOMAIN_ID"] = str(domain)
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("force_latency_probe", context=self.ctx,
                                      namespace=contract.DEFAULT_NAMESPACE)
        self.ex = make_executor("events", self.ctx)
        self.names = list(contract.ARM_JOINTS)
        self.want, self.arrived = -1, threading.Event()
        self._stamp = 0                   # ns, the newest stamp sent
        self.t_arrival = 0.0
        self.node.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                      qos_for(contract.JOINT_COMMAND))
        self.pub = self.node.create_publisher(JointState, contract.JOINT_STATES,
                                              qos_for(contract.JOINT_STATES))
        self.enable_cli = self.node.create_client(SetBool, contract.HYBRID_ENABLE)
        self.node.create_service(Trigger, contract.HOLD, lambda _q, r: r)
        self._setbool = SetBool
        self.msg = JointState(name=self.names, velocity=[0.0] * 9, effort=[0.0] * 9)
        self.stop = threading.Event()
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.stop.is_set() and self.ctx.ok():
            self.ex.spin_once(timeout_sec=0.05)

    def _on_command(self, msg) -> None:
        t = time.perf_counter()
        if msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == self.want:
            self.t_arrival = t
            self.arrived.set()

    def _next_stamp(self) -> int:
        """ns: now on the probe's clock, after every stamp sent before (hybrid_force drops
        a state older than the newest one used, or than its state_max_age)."""
        self._stamp = max(self.node.get_clock().now().nanoseconds, self._stamp + 1)
        return self._stamp

    def send(self, q, stamp_ns: int | None = None) -> None:
        stamp_ns = self._next_stamp() if stamp_ns is None else stamp_ns
        self.msg.header.stamp.sec, self.msg.header.stamp.nanosec = divmod(stamp_ns,
                                                                           1_000_000_000)
        self.msg.position = [float(v) for v in q]
        self.pub.publish(self.msg)

    def round_trip(self, q, timeout: float = 1.0) -> float | None:
        """Publish a state stamped now; seconds until the command carrying that stamp
        arrived (None: none within ``timeout``)."""
        self.want = self._next_stamp()
        self.arrived.clear()
        t0 = time.perf_counter()
        self.send(q, self.want)
        return self.t_arrival - t0 if self.arrived.wait(timeout) else None

    def enable(self, q) -> None:
        """Feed states at 100 Hz until hybrid_force is enabled."""
        _wait(self.enable_cli.service_is_ready, 20.0, "hybrid_force's enable service")
        _wait(lambda: self.pub.get_subscription_count() > 0, 20.0, "hybrid_force's "
              "joint_states subscription")
        for _ in range(20):
            self.send(q)
            time.sleep(0.01)
        fut = self.enable_cli.call_async(self._setbool.Request(data=True))
        while not fut.done():
            self.send(q)
            time.sleep(0.01)
        if not fut.result().success:
            raise RuntimeError(f"hybrid_force not enabled: {fut.result().message}")

    def close(self) -> None:
        import rclpy
        self.stop.set()
        self.thread.join(2.0)
        self.node.destroy_node()
        self.ex.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown(context=self.ctx)


#: (label, what runs on the other side) of the latency benchmark, in print order
LATENCY_CASES = (("trigger joint_states, executor events (default)", "hybrid_force",
                  {"trigger": "joint_states", "executor": "events"}),
                 ("trigger joint_states, executor single", "hybrid_force",
                  {"trigger": "joint_states", "executor": "single"}),
                 ("trigger timer 100 Hz, executor events", "hybrid_force",
                  {"trigger": "timer", "executor": "events"}),
                 ("floor: echo node, executor events", "echo", {"executor": "events"}),
                 ("floor: echo node, executor single", "echo", {"executor": "single"}))


def bench_latency(samples: int, domain: int, tmp: Path) -> dict:
    """Round trips probe -> node -> probe: the probe publishes one joint state, waits for
    the joint_command that carries its stamp, pauses 5-15 ms (random: a fixed pause would
    phase-lock with the timer trigger's 10 ms period), ``samples`` times per case."""
    q = [0.0, 0.5, 0.0, 0.6, 0.0, 0.5, 0.0, -1.0, 0.0]
    rng = np.random.default_rng(1)
    out = {}
    for i, (label, what, params) in enumerate(LATENCY_CASES):
        log = tmp / f"latency-{i}.log"
        if what == "echo":
            env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                       ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
            proc = subprocess.Popen([sys.executable, "-m", "hyperarm_control.benchmark.force_echo",
                                     params["executor"], "--ros-args"], env=env,
                                    stdout=open(log, "wb"), stderr=subprocess.STDOUT,
                                    start_new_session=True)
        else:
            proc = _launch("hybrid_force", domain, {**params, "stale_timeout": 1.0}, log)
        probe = _LatencyProbe(domain)
        try:
            if what == "hybrid_force":
                probe.enable(q)
            else:
                _wait(lambda: probe.pub.get_subscription_count() > 0, 20.0, "echo node")
            for _ in range(20):                      # warm-up (discovery, first messages)
                probe.round_trip(q)
                time.sleep(0.01)
            lat = []
            for _ in range(samples):
                dt = probe.round_trip(q)
                if dt is None:
                    raise RuntimeError(f"{label}: no command within 1 s (passive?); see {log}")
                lat.append(dt)
                time.sleep(rng.uniform(0.005, 0.015))
            t = np.array(lat) * 1e3
            out[label] = tuple(float(np.percentile(t, p)) for p in (50, 90, 99))
        finally:
            probe.close()
            _stop(proc)
    return out


def bench_outputs(domain: int, tmp: Path, plot: str | None) -> dict:
    from .force_probe import MockArm, step_response

    out, curves = {}, {}
    # each output at gains it is stable with on the mock at 100 Hz (the torque output
    # diverges at the position output's 800 N/m, 20 N·m/rad: see docs/benchmarks.md)
    gains = {"position": ([800.0] * 3 + [20.0] * 3, {}),
             "torque": ([300.0] * 3 + [3.0] * 3, {"damping": "[3.0,3.0,3.0,0.02,0.02,0.02]"})}
    for output in ("position", "torque"):
        k, extra = gains[output]
        mock = _launch("mock_driver", domain, {}, tmp / f"mock-{output}.log")
        hf = _launch("hybrid_force", domain, {
            "output": output, "stale_timeout": 0.5, **extra,
            "default_stiffness": "[" + ",".join(f"{v:g}.0" if v == int(v) else f"{v:g}"
                                               for v in k) + "]"}, tmp / f"hf-{output}.log")
        ros = _Ros(domain, driver=False)
        p = ros.probe
        try:
            arm = MockArm(p, _wait)
            arm.q_now()
            _wait(lambda: p.cmd_pub.get_subscription_count() > 0, 10.0, "mock")
            arm.move([0.35, -0.05, -0.05])
            assert p.enable(True).success
            ts, xs, goal = step_response(p, arm, stiffness=k, settle=1.0, duration=2.5)
            start = goal - np.array([0.0, 0.02, 0.0])      # the pose held before the step
            d = goal - start
            prog = (xs - start) @ d / float(d @ d)
            others = np.abs(xs[:, [0, 2]] - start[[0, 2]]).max()
            out[output] = (float(max(prog.max() - 1.0, 0.0)) * 100,
                           float(np.linalg.norm(xs[-1] - goal)) * 1e3, float(others) * 1e3)
            curves[output] = (ts, (xs[:, 1] - start[1]) * 1e3)
            p.enable(False)
        finally:
            ros.close()
            _stop(hf)
            _stop(mock)
    if plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4))
        for name, (ts, y) in curves.items():
            ax.plot(ts, y, label=f"{name} output, K {gains[name][0][0]:g} N/m, "
                    f"{gains[name][0][3]:g} N·m/rad")
        ax.axhline(20.0, color="k", lw=0.8, ls="--", label="goal (2 cm step)")
        ax.set_xlabel("time since the goal step (s)")
        ax.set_ylabel("tool y - start (mm), FK of joint_states")
        ax.set_title("hybrid_force on mock_driver: 2 cm step on a position axis")
        ax.legend()
        ax.grid(True, alpha=0.3)
        fig.tight_layout()
        fig.savefig(plot, dpi=100)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="force_benchmark", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--plot", default=None, help="PNG of the step responses")
    ap.add_argument("--only", choices=("core", "latency", "outputs"), default=None)
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "77")))
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="force_benchmark-"))
    if a.only in (None, "core"):
        for name, (med, p90, wall) in bench_core(a.cycles).items():
            print(f"core cycle ({name} output, law + estimate): CPU median {med:.3f} ms, "
                  f"p90 {p90:.3f} ms (wall median {wall:.3f} ms) over {a.cycles} cycles")
    if a.only in (None, "latency"):
        for name, (p50, p90, p99) in bench_latency(a.samples, a.domain, tmp).items():
            print(f"joint_states -> joint_command ({name}): p50 {p50:.2f} ms, "
                  f"p90 {p90:.2f} ms, p99 {p99:.2f} ms over {a.samples} samples")
    if a.only in (None, "outputs"):
        for name, (ov, err, other) in bench_outputs(a.domain, tmp, a.plot).items():
            print(f"2 cm step, {name} output: overshoot {ov:.1f} %, final error {err:.2f} mm, "
                  f"largest excursion of the other axes {other:.2f} mm")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
