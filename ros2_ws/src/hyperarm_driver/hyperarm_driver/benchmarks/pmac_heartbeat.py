"""pmac_heartbeat: how regularly the installed ``pmac_rail_driver`` feeds the safety PLC's
heartbeat under CPU load, to choose ``watchdog_timeout`` (issue 25 item 5).

Runs :class:`~hyperarm_driver.pmac.emulator.PmacEmulator` in this process and the installed
``pmac_rail_driver`` executable (the real node: rclpy executor, worker thread, the poll at
``rate``) as a child, with the parameters of a params file (``rail_arm.yaml`` by default)
except host/port, and ``burners`` busy-loop processes loading the CPUs. The heartbeat is
the ``P8001=P8001+1`` at the head of each poll line; its arrival times at the emulator give
the gaps the card's watchdog timer sees. Torque stays off (the watchdog is not armed, so it
never trips during the run); setpoints would only add heartbeats.

The gaps include this process's own scheduling delay (the emulator is Python too; a card
is not): the probe thread's lateness is printed beside them, so the two can be told apart.
The recommended timeout is ``margin`` times the largest gap, rounded up to 50 ms.

    python -m hyperarm_driver.benchmarks.pmac_heartbeat --duration 60 --burners 2

Needs the workspace built (``make setup``) and a ROS domain of its own (``ROS_DOMAIN_ID``).
"""
from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

from hyperarm_driver.pmac.emulator import PmacEmulator

HEARTBEAT = "P8001=P8001+1"


def _burn(stop) -> None:  # multiprocessing.Event
    x = 0
    while not stop.is_set():
        for _ in range(100000):
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF


def _default_params() -> str:
    from ament_index_python.packages import get_package_share_directory
    return str(Path(get_package_share_directory("hyperarm_bringup")) / "config" / "rail_arm.yaml")


def _driver_exe() -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix("hyperarm_driver")) / "lib" / "hyperarm_driver"
               / "pmac_rail_driver")


def _quantiles(xs: list[float]) -> dict[str, float]:
    s = sorted(xs)

    def q(p: float) -> float:
        return s[min(len(s) - 1, max(0, math.ceil(p * len(s)) - 1))]
    return {"p50": q(0.5), "p99": q(0.99), "p99.9": q(0.999), "max": s[-1]}


def measure(duration: float, burners: int, params_file: str, margin: float) -> int:
    stop = mp.Event()
    procs = [mp.Process(target=_burn, args=(stop,), daemon=True) for _ in range(burners)]
    lateness: list[float] = []
    probe_stop = threading.Event()

    def probe() -> None:           # this process's own scheduling delay (5 ms sleeps)
        while not probe_stop.is_set():
            t0 = time.monotonic()
            time.sleep(0.005)
            lateness.append(time.monotonic() - t0 - 0.005)

    with PmacEmulator(port=0, start_position=2000) as emu:
        cmd = [_driver_exe(), "--ros-args", "--params-file", params_file,
               "-p", "host:=127.0.0.1", "-p", f"port:={emu.port}", "-p", "log_period:=60.0"]
        drv = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 30.0
            while not any(HEARTBEAT in line for line in list(emu.log)):
                if drv.poll() is not None or time.monotonic() > deadline:
                    print("pmac_heartbeat: the driver did not start polling:\n"
                          + (drv.stdout.read() if drv.poll() is not None else ""),
                          file=sys.stderr)
                    return 1
                time.sleep(0.1)
            time.sleep(1.0)                   # past the connect and configure
            for p in procs:
                p.start()
            th = threading.Thread(target=probe, daemon=True)
            th.start()
            load0 = os.getloadavg()[0]
            t_start = time.monotonic()
            time.sleep(duration)
            t_end = time.monotonic()
            load1 = os.getloadavg()[0]
        finally:
            stop.set()
            probe_stop.set()
            drv.terminate()
            try:
                drv.wait(10.0)
            except subprocess.TimeoutExpired:
                drv.kill()
            for p in procs:
                p.join(2.0)
        with emu._lock:
            pairs = list(zip(emu.log_times, emu.log))
    beats = [t for t, line in pairs if HEARTBEAT in line and t_start <= t <= t_end]
    if len(beats) < 10:
        print(f"pmac_heartbeat: only {len(beats)} heartbeats in {duration:g} s", file=sys.stderr)
        return 1
    gaps = [b - a for a, b in zip(beats, beats[1:])]
    g, late = _quantiles(gaps), _quantiles(lateness)
    period = statistics.median(gaps)
    over = {thr: sum(x > thr for x in gaps) for thr in (0.1, 0.2, 0.3, 0.5)}
    worst = max(gaps)
    recommend = math.ceil(margin * worst / 0.05 - 1e-9) * 0.05
    print(f"pmac_heartbeat: {duration:g} s, {burners} burner process(es), load average "
          f"{load0:.1f} -> {load1:.1f} ({os.cpu_count()} CPUs); params {Path(params_file).name}")
    print(f"heartbeats: {len(beats)} ({len(beats) / (t_end - t_start):.1f}/s; "
          f"median gap {period * 1e3:.1f} ms)")
    print("gap ms:      " + "  ".join(f"{k} {v * 1e3:.1f}" for k, v in g.items()))
    print("gaps over:   " + "  ".join(f">{thr * 1e3:.0f} ms: {n}" for thr, n in over.items()))
    print("emulator process lateness ms (5 ms sleeps): "
          + "  ".join(f"{k} {v * 1e3:.1f}" for k, v in late.items()))
    print(f"recommended watchdog_timeout >= {margin:g} x {worst * 1e3:.0f} ms -> "
          f"{recommend:.2f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="pmac_heartbeat", description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="s of measurement (60)")
    ap.add_argument("--burners", type=int, default=2,
                    help="busy-loop processes loading the CPUs (2 = one per core here)")
    ap.add_argument("--params-file", default="",
                    help="driver parameters ('' = the installed rail_arm.yaml)")
    ap.add_argument("--margin", type=float, default=2.0,
                    help="recommended timeout = margin x the largest gap (2)")
    args = ap.parse_args(argv)
    if not 1.0 <= args.duration <= 3600.0 or not 0 <= args.burners <= 64 \
            or not args.margin >= 1.0:
        ap.error("duration 1..3600 s, burners 0..64, margin >= 1")
    return measure(args.duration, args.burners, args.params_file or _default_params(),
                   args.margin)


if __name__ == "__main__":
    sys.exit(main())
