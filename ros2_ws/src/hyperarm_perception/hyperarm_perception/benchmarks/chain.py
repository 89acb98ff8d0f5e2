"""Benchmark: the mock's camera chain end to end, as `make demo` runs it: rate and latency.

    python -m hyperarm_perception.benchmarks.chain [--seconds 30] [--warmup 10]

Starts the installed ``mock_driver`` (``detections:=none``: the camera is the chain's),
``mock_camera`` and ``marker_detector`` as processes on the shell's ``ROS_DOMAIN_ID`` (run it
on a domain of its own), waits ``--warmup`` s (the renderer's start), then for ``--seconds``
s records every ``detections`` message and prints:

- the rate of ``detections`` messages (Hz) and, per object, the share of them that carry it;
- the latency: when a message arrives minus its ``header.stamp`` (the exposure time), in
  ms: median, p95, max. It is the mock camera's exposure latency (the truth is published
  that long after the exposure) plus the render, the transport of the picture and the
  detection.

The arm stays in its start pose. docs/benchmarks.md keeps the figures.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _exe(package: str, name: str) -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix(package)) / "lib" / package / name)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hyperarm_perception.benchmarks.chain",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="s recorded (default 30)")
    ap.add_argument("--warmup", type=float, default=10.0,
                    help="s before recording: the renderer's start (default 10)")
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.warmup < 0:
        ap.error("--seconds must be > 0 and --warmup >= 0")
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from hyperarm_description import contract
    from hyperarm_description.freshness import stamp_seconds
    from hyperarm_description.qos import qos_for
    from hyperarm_interfaces.msg import Detections

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
             for cmd in ([_exe("hyperarm_driver", "mock_driver"), "--ros-args", "-p",
                          "detections:=none"],
                         [_exe("hyperarm_perception", "mock_camera")],
                         [_exe("hyperarm_perception", "marker_detector")])]
    rclpy.init()
    node = rclpy.create_node("camera_chain_benchmark", namespace=contract.DEFAULT_NAMESPACE)
    rows: list[tuple[float, float, tuple[str, ...]]] = []     # (arrival, stamp, names)
    node.create_subscription(
        Detections, contract.DETECTIONS,
        lambda m: rows.append((node.get_clock().now().nanoseconds * 1e-9,
                               stamp_seconds(m.header.stamp), tuple(m.names))),
        qos_for(contract.DETECTIONS))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        end = time.monotonic() + args.warmup
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.1)
        rows.clear()
        t0 = time.monotonic()
        while time.monotonic() - t0 < args.seconds:
            ex.spin_once(timeout_sec=0.1)
        span = time.monotonic() - t0
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        node.destroy_node()
        rclpy.try_shutdown()
    if not rows:
        print(f"no detections in {span:.1f} s: is the renderer up (MUJOCO_GL), the domain "
              f"free?", file=sys.stderr)
        return 1
    lat = 1e3 * np.array([a - s for a, s, _ in rows])
    print(f"detections: {len(rows)} messages in {span:.1f} s = {len(rows) / span:.2f} Hz")
    for name in sorted({n for *_, names in rows for n in names}):
        share = sum(name in names for *_, names in rows) / len(rows)
        print(f"  {name}: in {100 * share:.0f} % of them")
    print(f"latency (arrival - exposure stamp): median {np.median(lat):.1f} ms, p95 "
          f"{np.percentile(lat, 95):.1f} ms, max {lat.max():.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
