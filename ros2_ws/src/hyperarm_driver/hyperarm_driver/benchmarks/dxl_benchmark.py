"""dxl_benchmark: cycle time of the Dynamixel driver over dxl_emulator, the node's CPU use
at 100 Hz, and the wire-time estimate of one cycle at 1 and 4 Mbit/s.

Run: ``dxl_benchmark`` (``--help`` for options). Prints its figures; nothing is asserted.
The pty has no wire time, so a cycle over the emulator is an upper bound of the software
part (driver + SDK + the emulator's own Python + pty scheduling).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from hyperarm_description.model import load_description
from hyperarm_driver.dynamixel import protocol2 as p2
from hyperarm_driver.dynamixel.bus import READ_LEN, WRITE_LEN, DynamixelBus
from hyperarm_driver.dynamixel.config import BusConfig, bus_config_from_description
from hyperarm_driver.dynamixel.control_table import model_by_name
from hyperarm_driver.dynamixel.driver import DynamixelDriver
from hyperarm_driver.dynamixel.testing import EmulatorProcess


def wire_bytes(n: int, fast: bool) -> int:
    """Bytes on the wire in one cycle with ``n`` servos (exact packet sizes, no stuffing)."""
    ids = bytes(range(1, n + 1))
    read_inst = p2.build_packet(p2.BROADCAST_ID, p2.INST_FAST_SYNC_READ if fast
                                else p2.INST_SYNC_READ,
                                bytes([224, 0, READ_LEN, 0]) + ids, stuffing=False)
    if fast:
        replies = len(p2.build_fast_sync_status([(i, 0, bytes(READ_LEN)) for i in ids]))
    else:
        replies = n * len(p2.build_status(1, 0, bytes(READ_LEN)))
    write = p2.build_packet(p2.BROADCAST_ID, p2.INST_SYNC_WRITE,
                            bytes([224 + READ_LEN, 0, WRITE_LEN, 0])
                            + bytes(n * (1 + WRITE_LEN)), stuffing=False)
    return len(read_inst) + replies + len(write)


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_cycles(cycles: int, fast: bool) -> dict[str, float]:
    """Time ``cycles`` cycles. The description's MX(2.0) servos do not answer Fast Sync
    Read (as real ones), so the fast run emulates them as XM430-W350s."""
    config = bus_config_from_description(load_description())
    args: list[str] = []
    if fast:
        xm = model_by_name("XM430-W350")
        args = [a for j in config.joints if j.model.series == "MX"
                for a in ("--model", f"{j.id}={xm.name}")]
        config = BusConfig(tuple(replace(j, model=xm) if j.model.series == "MX" else j
                                 for j in config.joints))
    with EmulatorProcess(*args) as emu:
        bus = DynamixelBus(config, emu.link, fast_sync_read=fast)
        drv = DynamixelDriver(bus)
        drv.connect()
        drv.set_torque(True)
        for _ in range(50):
            drv.cycle()
        bus.stats.cycle_times.clear()
        rng = np.random.default_rng(0)
        wall, cpu = [], []
        failed_cycles = 0
        names = drv.names
        for _ in range(cycles):
            drv.command(names, rng.uniform(-0.5, 0.5, len(names)).tolist())
            t0, c0 = time.perf_counter(), time.process_time()
            ok = drv.cycle() is not None
            if not ok:
                failed_cycles += 1
                if not drv.connected:
                    raise RuntimeError(f"port lost: {drv.last_error}")
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        # the driver's own computation, without I/O: decode + goals
        raw = np.zeros((len(names), READ_LEN), dtype=np.uint8)
        t0 = time.perf_counter()
        for _ in range(cycles):
            bus._decode(raw)
            bus.goal_ticks(drv.goal_position)
            bus.goal_current(drv.goal_effort)
        compute = (time.perf_counter() - t0) / cycles
        failures = bus.stats.failures
        retries = bus.stats.retries
        drv.shutdown("release")
    w = np.array(wall) * 1e3
    return {"median_ms": float(np.median(w)), "p99_ms": float(np.percentile(w, 99)),
            "max_ms": float(w.max()), "cpu_ms": 1e3 * statistics.fmean(cpu),
            "compute_ms": compute * 1e3, "failures": failures, "retries": retries,
            "failed_cycles": failed_cycles, "fast": float(bus.fast)}


def bench_node(seconds: float, rate: float) -> dict[str, float]:
    from ament_index_python.packages import get_package_prefix

    exe = Path(get_package_prefix("hyperarm_driver")) / "lib" / "hyperarm_driver" / \
        "dynamixel_driver"
    with tempfile.TemporaryDirectory() as tmp, EmulatorProcess(workdir=tmp) as emu:
        env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 60),
                   ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        proc = subprocess.Popen(
            [str(exe), "--ros-args", "-p", f"port:={emu.link}", "-p", f"rate:={rate}",
             "-p", "torque_on_start:=true", "-p", "shutdown_torque:=release"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        try:
            time.sleep(3.0)   # start-up
            c0, e0, t0 = _cpu_seconds(proc.pid), _cpu_seconds(emu.proc.pid), time.monotonic()
            time.sleep(seconds)
            c1, e1, t1 = _cpu_seconds(proc.pid), _cpu_seconds(emu.proc.pid), time.monotonic()
            reads = emu.ctl("stats")["instructions"]
        finally:
            proc.send_signal(2)
            proc.wait(timeout=15)
    return {"node_cpu_pct": 100 * (c1 - c0) / (t1 - t0),
            "emulator_cpu_pct": 100 * (e1 - e0) / (t1 - t0),
            "sync_reads": float(reads.get("0x8a", 0) + reads.get("0x82", 0))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dxl_benchmark", description=__doc__.split("\n")[0])
    ap.add_argument("--cycles", type=int, default=2000, help="cycles to time (default 2000)")
    ap.add_argument("--node-seconds", type=float, default=10.0,
                    help="how long to measure the node's CPU use (0 = skip)")
    ap.add_argument("--rate", type=float, default=100.0, help="node rate for the CPU figure")
    args = ap.parse_args(argv)
    n = 10
    print(f"dxl_benchmark: {n} servos (description; the fast run with its MX servos as "
          f"XM430-W350, MX(2.0) has no Fast Sync Read), cycle = sync read "
          f"({READ_LEN} B/servo) + sync write ({WRITE_LEN} B/servo)")
    for fast in (True, False):
        r = bench_cycles(args.cycles, fast)
        kind = "fast sync read" if r["fast"] else "plain sync read"
        print(f"  cycle over the emulator, {kind}: median {r['median_ms']:.3f} ms, "
              f"p99 {r['p99_ms']:.3f} ms, max {r['max_ms']:.3f} ms; driver CPU "
              f"{r['cpu_ms']:.3f} ms/cycle (SDK polls while waiting); pure computation "
              f"{r['compute_ms'] * 1e3:.1f} us/cycle; failed transactions {r['failures']} "
              f"(retried {r['retries']}), failed cycles {r['failed_cycles']}")
    for fast in (True, False):
        b = wire_bytes(n, fast)
        print(f"  wire estimate ({'fast' if fast else 'plain'} sync read): {b} bytes/cycle = "
              f"{b * 10 / 1e6 * 1e3:.3f} ms at 1 Mbit/s, {b * 10 / 4e6 * 1e3:.3f} ms at "
              f"4 Mbit/s (10 bits/byte, return delay 0, excluding USB latency)")
    if args.node_seconds > 0:
        r = bench_node(args.node_seconds, args.rate)
        print(f"  node at {args.rate:g} Hz for {args.node_seconds:g} s: CPU "
              f"{r['node_cpu_pct']:.1f} % of one core (emulator {r['emulator_cpu_pct']:.1f} %), "
              f"{r['sync_reads']:.0f} sync reads served in total")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
