"""host_benchmark: figures of host-motion compensation (docs/benchmarks.md, docs/host.md).

1. ``core``: thread CPU time of one cycle of the ROS-free core on a rail motion
   (``Compensator.step`` + ``ReactionModel.wrench``): median and p90.
2. ``latency``: joint_states in -> joint_command out through ROS: the installed
   ``host_compensation`` (rail_arm) in its own process, driven ping-pong by a probe (one
   joint state with a unique stamp, wait for the command carrying that stamp): p50, p90, p99.

3. ``mount``: issue 24 item 4, ``uav_sway_passive`` from 10 ordinary postures x 3 seeds
   on the mock's simulation (``host_sim.mount_study``, several minutes): each run's truth
   RMS / max error and the mount's motion, and whether all are within 3 mm RMS, 8 mm max.

The PNG figures of docs/host.md (tool error, reaction over time) from the mock's
simulation: ``ros2 run hyperarm_tasks host_plots DIR`` (they run the figure-8 task).

Usage: host_benchmark [--cycles N] [--samples N] [--only core|latency|mount] [--domain D]
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from hyperarm_description import contract
from hyperarm_description.model import load_description

from ..host import Compensator, RailHost, ReactionModel
from hyperarm_ik.kinematics import Kinematics

Q0 = [1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726]


def bench_core(cycles: int) -> tuple[float, float]:
    kin = Kinematics(variant="arm")
    rail = RailHost(load_description(variant="rail_arm"))
    comp, reaction = Compensator(kin), ReactionModel(kin)
    comp.start(np.array(Q0), rail.state(0.0))
    times = []
    for i in range(cycles):
        t = i * 0.01
        t0 = time.thread_time()
        step = comp.step(rail.state(0.2 * math.sin(t), 0.2 * math.cos(t)), 0.03, 0.01)
        reaction.wrench(step.q, np.zeros(9))
        times.append(time.thread_time() - t0)
    ms = np.array(times) * 1e3
    return float(np.median(ms)), float(np.percentile(ms, 90))


def bench_latency(samples: int, domain: int) -> tuple[float, float, float]:
    import rclpy
    from ament_index_python.packages import get_package_prefix
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool

    from hyperarm_description.qos import qos_for

    exe = Path(get_package_prefix("hyperarm_control")) / "lib" / "hyperarm_control" / "host_compensation"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    log = Path(tempfile.mkdtemp()) / "host_compensation.log"
    proc = subprocess.Popen([str(exe), "--ros-args", "-p", "variant:=rail_arm", "-p",
                             "stale_timeout:=1.0"], stdout=open(log, "wb"),
                            stderr=subprocess.STDOUT, env=env, start_new_session=True)
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    ex = EventsExecutor(context=ctx)      # the probe's own overhead stays small
    node = Node("host_benchmark", namespace=contract.DEFAULT_NAMESPACE, context=ctx)
    got: dict[int, float] = {}
    lock = threading.Lock()
    arrived = threading.Event()

    def on_cmd(msg: JointState) -> None:
        with lock:
            got[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = time.monotonic()
        arrived.set()

    node.create_subscription(JointState, contract.JOINT_COMMAND, on_cmd,
                             qos_for(contract.JOINT_COMMAND))
    pub = node.create_publisher(JointState, contract.JOINT_STATES,
                                qos_for(contract.JOINT_STATES))
    cli = node.create_client(SetBool, contract.HOST_COMP_ENABLE)
    ex.add_node(node)
    stop = threading.Event()
    thread = threading.Thread(target=lambda: [ex.spin_once(timeout_sec=0.005)
                                              for _ in iter(stop.is_set, True)], daemon=True)
    thread.start()
    names = [contract.RAIL_JOINT] + list(contract.ARM_JOINTS)

    def send(x: float) -> int:
        msg = JointState()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.name = names
        msg.position = [x] + Q0
        msg.velocity = [0.0] * len(names)
        pub.publish(msg)
        return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec

    def wait(cond, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        while not (v := cond()):
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out waiting for {what}\n{log.read_text()[-2000:]}")
            arrived.wait(0.002)     # woken by a command's arrival
            arrived.clear()
        return v

    try:
        wait(cli.service_is_ready, 30.0, "host_compensation")
        for _ in range(20):
            send(0.0)
            time.sleep(0.01)
        fut = cli.call_async(SetBool.Request(data=True))
        res = wait(lambda: fut.done() and fut.result(), 10.0, "enable")
        if not res.success:
            raise RuntimeError(res.message)
        lat = []
        for k in range(samples):
            t0 = time.monotonic()
            key = send(0.001 * math.sin(k * 0.1))
            lat.append(wait(lambda: got.get(key), 1.0, "command") - t0)
            time.sleep(0.01)
        ms = np.array(lat) * 1e3
        return tuple(float(np.percentile(ms, p)) for p in (50, 90, 99))
    finally:
        stop.set()
        thread.join(2.0)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="host_benchmark", description=__doc__.split("\n\n")[0],
                                 epilog="The PNG figures of docs/host.md: "
                                        "ros2 run hyperarm_tasks host_plots DIR")
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--only", choices=("core", "latency", "mount"))
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    a = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.1f}")
    if a.only == "mount":
        from .host_sim import mount_study

        runs = mount_study()
        for r in runs:
            print(f"seed {r['seed']} q0 {np.round(r['q0'], 2).tolist()}: RMS "
                  f"{r['rms'] * 1e3:.2f} mm, max {r['max'] * 1e3:.2f} mm, {r['deg']:.2f} deg, "
                  f"mount {r['mount'] * 1e3:.1f} mm")
        ok = all(r["rms"] < 3e-3 and r["max"] < 8e-3 for r in runs)
        print(f"{len(runs)} runs, worst RMS {max(r['rms'] for r in runs) * 1e3:.2f} mm, worst "
              f"max {max(r['max'] for r in runs) * 1e3:.2f} mm: "
              f"{'all within' if ok else 'NOT all within'} 3 mm RMS, 8 mm max")
        return
    if a.only in (None, "core"):
        med, p90 = bench_core(a.cycles)
        print(f"core cycle (step + reaction), CPU: median {med:.3f} ms, p90 {p90:.3f} ms")
    if a.only in (None, "latency"):
        p50, p90, p99 = bench_latency(a.samples, a.domain)
        print(f"joint_states -> joint_command through ROS: p50 {p50:.2f} ms, p90 {p90:.2f} ms, "
              f"p99 {p99:.2f} ms")


if __name__ == "__main__":
    main()
