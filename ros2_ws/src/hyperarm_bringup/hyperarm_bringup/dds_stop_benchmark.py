"""How long rclpy's ``destroy_node`` takes when many node processes stop at once, per Fast DDS
transport: shared memory (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, rmw_fastrtps' own
shared-memory + UDP pair) or UDP loopback alone (``SYSTEM_DEFAULT`` with
``config/fastdds_localhost.xml``, the tests' set-up). docs/benchmarks.md, "Stopping many
nodes at once", has the figures.

Each round starts ``--processes`` node processes, each with ``--endpoints`` publishers and as
many subscriptions on shared topics (100 Hz), waits ``--settle`` s, sends SIGINT to all at
once, and reads from each its destroy time (wall and the main thread's CPU). Prints, per
round, the slowest and the median destroy and the slowest exit after the signal.

    python -m hyperarm_bringup.dds_stop_benchmark --processes 16 --endpoints 30 --rounds 5

Uses the shell's ``ROS_DOMAIN_ID``: run it on a domain of its own.
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

TRANSPORTS = ("shm", "udp")


def localhost_profile() -> Path:
    """config/fastdds_localhost.xml of the installed package (else the source tree's)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory("hyperarm_bringup")) / "config"
    except Exception:   # noqa: BLE001 - not installed: the source tree
        path = Path(__file__).resolve().parents[1] / "config"
    return path / "fastdds_localhost.xml"


def transport_env(transport: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if transport == "shm":
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    elif transport == "udp":
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(localhost_profile())
    else:
        raise ValueError(f"transport {transport!r}: one of {', '.join(TRANSPORTS)}")
    return env


def child(endpoints: int) -> int:
    """One node process: runs until SIGINT, then prints ``destroy <wall s> <cpu s>``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"dds_stop_{os.getpid()}")
    pubs = [node.create_publisher(JointState, f"dds_stop_{i}", 10) for i in range(endpoints)]
    for i in range(endpoints):
        node.create_subscription(JointState, f"dds_stop_{i}", lambda _m: None, 10)
    msg = JointState(name=[f"joint{j}" for j in range(9)], position=[0.0] * 9)
    node.create_timer(0.01, lambda: [p.publish(msg) for p in pubs])
    ex = SingleThreadedExecutor()
    ex.add_node(node)

    def spin() -> None:
        while not stop.is_set():
            ex.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    print("ready", flush=True)
    while not stop.is_set():
        stop.wait(0.5)
    spinner.join(2.0)
    ex.shutdown()
    c0, t0 = time.thread_time(), time.monotonic()
    node.destroy_node()
    t1, c1 = time.monotonic(), time.thread_time()
    rclpy.try_shutdown()
    print(f"destroy {t1 - t0:.4f} {c1 - c0:.4f}", flush=True)
    return 0


def one_round(transport: str, processes: int, endpoints: int, settle: float) -> dict:
    env = transport_env(transport)
    cmd = [sys.executable, "-m", "hyperarm_bringup.dds_stop_benchmark", "--child",
           str(endpoints)]
    procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True)
             for _ in range(processes)]
    try:
        for p in procs:
            if p.stdout.readline().strip() != "ready":
                raise RuntimeError("a node process did not start")
        time.sleep(settle)
        for p in procs:
            p.send_signal(signal.SIGINT)
        sent = time.monotonic()
        exits, walls, cpus = [], [], []
        for p in procs:
            out, _ = p.communicate(timeout=60)
            exits.append(time.monotonic() - sent)
            for line in out.splitlines():
                if line.startswith("destroy "):
                    wall, cpu = line.split()[1:3]
                    walls.append(float(wall))
                    cpus.append(float(cpu))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    if len(walls) != processes:
        raise RuntimeError(f"{processes - len(walls)} node processes reported no destroy time")
    return {"slowest": max(walls), "median": statistics.median(walls),
            "cpu_of_slowest": cpus[walls.index(max(walls))], "last_exit": max(exits)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hyperarm_bringup.dds_stop_benchmark",
                                 description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--processes", type=int, default=16, help="node processes (default 16)")
    ap.add_argument("--endpoints", type=int, default=30,
                    help="publishers, and as many subscriptions, per node (default 30)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds per transport (default 5)")
    ap.add_argument("--transport", choices=(*TRANSPORTS, "both"), default="both")
    ap.add_argument("--settle", type=float, default=1.5,
                    help="s between the last node ready and the signal (default 1.5)")
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        return child(args.child)
    if min(args.processes, args.endpoints, args.rounds) < 1 or args.settle < 0:
        ap.error("--processes, --endpoints and --rounds must be at least 1, --settle >= 0")
    transports = TRANSPORTS if args.transport == "both" else (args.transport,)
    print(f"{args.processes} processes x {args.endpoints} publishers + {args.endpoints} "
          f"subscriptions, ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}")
    for transport in transports:
        for r in range(args.rounds):
            res = one_round(transport, args.processes, args.endpoints, args.settle)
            print(f"{transport} round {r + 1}: destroy slowest {res['slowest']:.3f} s "
                  f"(its CPU {res['cpu_of_slowest']:.3f} s), median {res['median']:.3f} s; "
                  f"last exit {res['last_exit']:.3f} s after the signal", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
