"""pmac_benchmark: command round-trip time of the PMAC client over loopback (or to a card).

Targets (each served by a separate process, so the server does not share the client's GIL):

- ``ack``: a minimal server answering every GETRESPONSE with ``0<CR><ACK>`` at once: the
  client's own cost plus the loopback (what the < 1 ms p50 target is about);
- ``emulator``: ``pmac_emulator`` (command interpretation and motion simulation included);
- ``--host H --port P``: an existing server or a real card (read-only commands only).

Commands timed: ``#1P`` (one query), ``#1P#1V#1F#1?`` (the poll without the safety PLC)
and, on the loopback targets only (it writes the heartbeat P-variable), the driver's poll
with the safety PLC ``P8001=P8001+1 #1P#1V#1F#1? P8003``. Prints p50/p95/p99/max in ms,
commands/s, and the client's CPU time per command.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import socket
import statistics
import sys
import time

from hyperarm_driver.pmac import protocol as proto
from hyperarm_driver.pmac.client import PmacClient

COMMANDS = ("#1P", "#1P#1V#1F#1?")
WATCHDOG_POLL = "P8001=P8001+1 #1P#1V#1F#1? P8003"   # writes: not sent to a real card


def _ack_server(port_out) -> None:   # multiprocessing.Connection
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port_out.send(srv.getsockname()[1])
    conn, _ = srv.accept()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    buf = b""
    while True:
        data = conn.recv(4096)
        if not data:
            return
        buf += data
        while len(buf) >= proto.HEADER_SIZE:
            h = proto.decode_header(buf)
            n = proto.HEADER_SIZE + (h.length if h.request_type == proto.VR_DOWNLOAD else 0)
            if len(buf) < n:
                break
            buf = buf[n:]
            conn.sendall(proto.FLUSH_REPLY if h.request == proto.Request.FLUSH else b"0\r\x06")


def _emulator_server(port_out) -> None:
    from hyperarm_driver.pmac.emulator import PmacEmulator
    emu = PmacEmulator(port=0).start()
    port_out.send(emu.port)
    while True:
        time.sleep(3600)


def measure(client: PmacClient, command: str, n: int, warmup: int) -> dict[str, float]:
    for _ in range(warmup):
        client.command(command)
    samples = []
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for _ in range(n):
        t = time.perf_counter()
        client.command(command)
        samples.append(time.perf_counter() - t)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    samples.sort()
    q = statistics.quantiles(samples, n=100, method="inclusive")
    return {"p50": q[49] * 1e3, "p95": q[94] * 1e3, "p99": q[98] * 1e3,
            "max": samples[-1] * 1e3, "rate": n / wall, "cpu_us": cpu / n * 1e6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="pmac_benchmark", description=__doc__.split("\n")[0])
    ap.add_argument("--target", choices=("ack", "emulator", "both"), default="both")
    ap.add_argument("--host", help="benchmark an existing server/card instead")
    ap.add_argument("--port", type=int, default=1025)
    ap.add_argument("-n", type=int, default=5000, help="timed commands per case (default 5000)")
    ap.add_argument("--warmup", type=int, default=200)
    args = ap.parse_args(argv)
    if args.n < 100:
        ap.error("-n must be at least 100")

    cases: list[tuple[str, str, int, mp.Process | None]] = []
    if args.host:
        cases.append((f"{args.host}:{args.port}", args.host, args.port, None))
    else:
        ctx = mp.get_context("spawn")
        targets = ("ack", "emulator") if args.target == "both" else (args.target,)
        for name in targets:
            rx, tx = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_ack_server if name == "ack" else _emulator_server,
                               args=(tx,), daemon=True)
            proc.start()
            if not rx.poll(30):
                print(f"pmac_benchmark: {name} server did not start", file=sys.stderr)
                return 1
            cases.append((name, "127.0.0.1", rx.recv(), proc))

    print(f"pmac_benchmark: Python {sys.version.split()[0]}, n={args.n} per case, "
          f"warm-up {args.warmup}")
    print(f"{'server':<10} {'command':<14} {'p50 ms':>8} {'p95 ms':>8} {'p99 ms':>8} "
          f"{'max ms':>8} {'cmd/s':>8} {'client CPU us/cmd':>18}")
    try:
        for name, host, port, proc in cases:
            with PmacClient(host, port, timeout=1.0) as client:
                for cmd in COMMANDS + ((WATCHDOG_POLL,) if proc is not None else ()):
                    r = measure(client, cmd, args.n, args.warmup)
                    print(f"{name:<10} {cmd:<14} {r['p50']:8.3f} {r['p95']:8.3f} "
                          f"{r['p99']:8.3f} {r['max']:8.3f} {r['rate']:8.0f} "
                          f"{r['cpu_us']:18.1f}", flush=True)
    finally:
        for *_, proc in cases:
            if proc is not None:
                proc.terminate()
                proc.join(5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
