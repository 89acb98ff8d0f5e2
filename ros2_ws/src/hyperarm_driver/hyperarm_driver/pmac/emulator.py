"""pmac_emulator: a Turbo PMAC on 127.0.0.1 speaking the Ethernet protocol (for tests and demos).

Simulated, per motor (counts and seconds inside; the card's units on the wire):

- jog motion with a trapezoidal profile: ``J=`` (to position), ``J+``/``J-`` (continuous),
  ``J/`` (stop and hold; closes the loop), ``K`` (kill), speed Ixx22 (counts/ms),
  acceleration Ixx19 (counts/ms²) limited by Ixx20 (ms) when non-zero; soft limits Ixx13/Ixx14;
- home search ``HM`` (speed and direction Ixx23 counts/ms, offset Ixx26 1/16 count, switch at
  a physical position) and ``HMZ`` (zero here);
- hardware overtravel switches at physical positions: motion into them stops at once;
- following error = servo lag x velocity + an injectable disturbance; fatal (Ixx11, 1/16
  count) kills the motor, warning (Ixx12) is flagged; amplifier fault (injected) kills it;
- queries ``P`` (counts), ``V`` (counts per servo cycle, I10), ``F`` (counts), ``?`` (two
  24-bit status words), ``Innn`` / ``Innn=v`` / ``Innn..mmm``, ``VER``, ``TYPE``;
- ``<BELL>ERR003<CR>`` for unknown or malformed commands, ``ERR004`` for non-ASCII bytes;
- link faults for tests: :meth:`PmacEmulator.drop_connections`, ``mute`` (no answers),
  ``refuse`` (connections closed at once);
- optionally the RS-232 protocol on a pseudo-terminal (:meth:`PmacEmulator.serve_pty`).

Command line: ``pmac_emulator --port 0`` prints ``pmac_emulator: listening on 127.0.0.1:PORT``.
Only 127.0.0.1 is ever bound.
"""
from __future__ import annotations

import argparse
import math
import re
import signal
import socket
import sys
import threading
import time
from dataclasses import dataclass, field

from . import protocol as proto
from .axis import I10_DEFAULT, MotorStatus

__all__ = ["PmacEmulator", "MotorSim", "main"]

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:E[-+]?\d+)?"
_RE_MOTOR = re.compile(r"#(\d+)")
_RE_NUM = re.compile(_NUM)
_RE_IVAR = re.compile(rf"I(\d+)(?:\.\.(\d+)|=({_NUM}))?")
_MAX_STEP = 1e-3   # s, integration step
_LAG = 0.002       # s, servo lag: following error = lag * velocity

# Turbo PMAC factory defaults of the motor I-variables the emulator uses.
_MOTOR_DEFAULTS = {0: 1.0, 11: 32000.0, 12: 16000.0, 13: 0.0, 14: 0.0, 19: 0.015625,
                   20: 250.0, 21: 50.0, 22: 32.0, 23: 32.0, 26: 0.0, 28: 160.0}


class _CmdError(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


def _fmt(x: float) -> str:
    if float(x).is_integer():
        return str(int(x))
    return f"{x:.4f}".rstrip("0").rstrip(".")


@dataclass
class MotorSim:
    """One simulated motor. ``pos`` is the commanded physical position (counts)."""

    number: int
    pos: float = 0.0
    vel: float = 0.0                # counts/s
    ref: float = 0.0                # physical position of the motor zero
    mode: str = "idle"              # idle | jog | home_search | home_return
    target: float = 0.0             # physical counts (jog, home_return)
    closed_loop: bool = False       # power-on: killed, as a card with Ixx80=0
    homed: bool = False
    amp_fault: bool = False
    fatal_fe: bool = False
    stopped_on_limit: bool = False
    stopped_on_desired_limit: bool = False
    amp_fault_input: bool = False   # injected amplifier fault line
    disturbance: float = 0.0        # counts of extra following error (e.g. a jam)
    home_at: float = 0.0            # physical position of the home switch
    neg_limit_at: float = -math.inf
    pos_limit_at: float = math.inf
    ivars: dict[int, float] = field(default_factory=lambda: dict(_MOTOR_DEFAULTS))

    # -- derived --------------------------------------------------------------------------
    @property
    def following_error(self) -> float:
        return (_LAG * self.vel + self.disturbance) if self.closed_loop else 0.0

    @property
    def actual(self) -> float:
        return self.pos - self.following_error

    @property
    def neg_limit(self) -> bool:
        return self.pos <= self.neg_limit_at

    @property
    def pos_limit(self) -> bool:
        return self.pos >= self.pos_limit_at

    def _speed_accel(self, speed_ivar: int = 22) -> tuple[float, float]:
        v = abs(self.ivars[speed_ivar]) * 1e3
        a = self.ivars[19] * 1e6
        if self.ivars[20] > 0:
            a = min(a, v / (self.ivars[20] * 1e-3)) if v > 0 else a
        return v, max(a, 1e-9)

    def status(self) -> MotorStatus:
        fe16 = abs(self.following_error) * 16
        return MotorStatus.from_flags(
            activated=self.ivars[0] != 0, neg_limit=self.neg_limit, pos_limit=self.pos_limit,
            amp_enabled=self.closed_loop, open_loop=not self.closed_loop,
            move_timer=self.mode != "idle", desired_velocity_zero=self.vel == 0.0,
            home_search=self.mode in ("home_search", "home_return"),
            stopped_on_desired_limit=self.stopped_on_desired_limit,
            stopped_on_position_limit=self.stopped_on_limit, home_complete=self.homed,
            amp_fault=self.amp_fault, fatal_following_error=self.fatal_fe,
            warning_following_error=self.ivars[12] > 0 and fe16 > self.ivars[12],
            in_position=self.closed_loop and self.mode == "idle"
            and fe16 <= max(self.ivars[28], 16.0))

    # -- commands -------------------------------------------------------------------------
    def kill(self) -> None:
        self.pos = self.actual
        self.closed_loop = False
        self.vel = 0.0
        self.mode = "idle"

    def enable(self) -> None:
        """J/ : stop a move, or close the loop at the present position."""
        if not self.closed_loop:
            if self.amp_fault_input:
                self.amp_fault = True
                return
            self.amp_fault = self.fatal_fe = False
            self.closed_loop = True
            self.vel = 0.0
            self.mode = "idle"
            self._check_following_error()
            return
        if self.mode != "idle":
            v, a = self._speed_accel()
            stop = self.vel * abs(self.vel) / (2 * a)
            self.mode, self.target = "jog", self.pos + stop

    def jog(self, target_counts: float) -> None:
        """Jog to a position in motor counts (relative to the motor zero)."""
        self.enable_if_needed()
        if not self.closed_loop:
            return
        self.stopped_on_limit = self.stopped_on_desired_limit = False
        t = target_counts
        hi, lo = self.ivars[13], self.ivars[14]
        if hi != 0 and t > hi:
            t, self.stopped_on_desired_limit = hi, True
        if lo != 0 and t < lo:
            t, self.stopped_on_desired_limit = lo, True
        phys = t + self.ref
        if (phys > self.pos and self.pos_limit) or (phys < self.pos and self.neg_limit):
            self.stopped_on_limit = True     # the card will not move into an active limit
            return
        self.mode, self.target = "jog", phys

    def enable_if_needed(self) -> None:
        if not self.closed_loop:
            self.enable()

    def home(self) -> None:
        self.enable_if_needed()
        if not self.closed_loop:
            return
        self.homed = False
        self.stopped_on_limit = False
        if self.ivars[23] == 0:
            self.home_zero()
            return
        self.mode = "home_search"

    def home_zero(self) -> None:
        self.ref = self.pos
        self.homed = True
        self.mode = "idle"

    # -- simulation -----------------------------------------------------------------------
    def step(self, dt: float) -> None:
        if not self.closed_loop:
            return
        if self.mode == "idle":
            if self.vel != 0.0:
                self.vel = 0.0
            self._check_following_error()
            return
        if self.mode == "home_search":
            v, a = self._speed_accel(23)
            direction = 1.0 if self.ivars[23] > 0 else -1.0
            goal = direction * 1e15
        else:
            v, a = self._speed_accel()
            goal = self.target
        dist = goal - self.pos
        v_des = math.copysign(min(v, math.sqrt(2 * a * abs(dist))), dist) if dist else 0.0
        dv = max(-a * dt, min(a * dt, v_des - self.vel))
        self.vel += dv
        new = self.pos + self.vel * dt
        if self.mode != "home_search" and (goal - new) * dist <= 0:  # reached or passed
            new, self.vel = goal, 0.0
        prev, self.pos = self.pos, new
        if self.mode == "home_search" and (prev - self.home_at) * (new - self.home_at) <= 0:
            # trigger captured: motor zero = trigger + Ixx26 (units of 1/16 count)
            self.ref = self.home_at + self.ivars[26] / 16.0
            self.mode, self.target = "home_return", self.ref
        elif self.pos >= self.pos_limit_at and self.vel > 0 or \
                self.pos <= self.neg_limit_at and self.vel < 0:
            self.pos = min(max(self.pos, self.neg_limit_at), self.pos_limit_at)
            self.vel, self.mode, self.stopped_on_limit = 0.0, "idle", True   # home failed too
        elif self.mode != "home_search" and self.pos == goal:
            if self.mode == "home_return":
                self.homed = True
            self.mode = "idle"
        self._check_following_error()

    def _check_following_error(self) -> None:
        if self.amp_fault_input and self.closed_loop:
            self.amp_fault = True
            self.kill()
        elif self.ivars[11] > 0 and abs(self.following_error) * 16 > self.ivars[11]:
            self.fatal_fe = True
            self.kill()


class PmacEmulator:
    """A Turbo PMAC on 127.0.0.1 (TCP). ``port=0`` picks a free port (see :attr:`port`).

    ``motors``: how many motors (1..) are activated. Per-motor physical setup in counts:
    ``start_position``, ``home_switch``, ``limits`` (neg, pos). Thread-safe; use as a context
    manager or call :meth:`start` / :meth:`stop`.
    """

    def __init__(self, port: int = 0, motors: int = 1, start_position: float = 0.0,
                 home_switch: float = 0.0, limits: tuple[float, float] = (-math.inf, math.inf),
                 i10: float = I10_DEFAULT) -> None:
        if not 1 <= motors <= 32:
            raise ValueError(f"motors must be 1..32, got {motors}")
        if not limits[0] < limits[1]:
            raise ValueError(f"limits must be (neg, pos) with neg < pos, got {limits}")
        self._req_port = int(port)
        self.globals: dict[int, float] = {10: float(i10), 3: 2.0, 6: 1.0}
        self.motors = {m: MotorSim(m, pos=float(start_position), home_at=float(home_switch),
                                   neg_limit_at=float(limits[0]), pos_limit_at=float(limits[1]))
                       for m in range(1, motors + 1)}
        self._lock = threading.RLock()
        self._t = time.monotonic()
        self._server: socket.socket | None = None
        self._conns: set[socket.socket] = set()
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self.mute = False      # read requests, never answer (an unresponsive card)
        self.refuse = False    # close new connections at once
        self.requests = 0

    # -- life cycle -----------------------------------------------------------------------
    @property
    def port(self) -> int:
        if self._server is None:
            raise RuntimeError("emulator not started")
        return self._server.getsockname()[1]

    def start(self) -> "PmacEmulator":
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind(("127.0.0.1", self._req_port))
        srv.listen(8)
        srv.settimeout(0.1)
        self._server = srv
        self._running.set()
        t = threading.Thread(target=self._accept_loop, name="pmac-emu-accept", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def stop(self) -> None:
        self._running.clear()
        self.drop_connections()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()
        if self._server is not None:
            self._server.close()

    def __enter__(self) -> "PmacEmulator":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def drop_connections(self) -> None:
        """Close every client connection now (the client sees EOF / reset)."""
        with self._lock:
            conns, self._conns = list(self._conns), set()
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()

    @property
    def connection_count(self) -> int:
        with self._lock:
            return len(self._conns)

    # -- fault injection and inspection ---------------------------------------------------
    def motor(self, n: int) -> MotorSim:
        """The simulated motor ``n`` (advanced to now); hold no reference across calls."""
        with self._lock:
            self._advance()
            return self.motors[n]

    def set_amp_fault(self, n: int, active: bool = True) -> None:
        with self._lock:
            self._advance()
            m = self.motors[n]
            m.amp_fault_input = bool(active)
            m._check_following_error()

    def set_disturbance(self, n: int, counts: float) -> None:
        """Extra following error (counts) while the loop is closed, e.g. a jammed carriage."""
        with self._lock:
            self._advance()
            m = self.motors[n]
            m.disturbance = float(counts)
            m._check_following_error()

    # -- simulation -----------------------------------------------------------------------
    def _advance(self) -> None:
        now = time.monotonic()
        dt_total, self._t = now - self._t, now
        busy = [m for m in self.motors.values() if m.closed_loop and
                (m.mode != "idle" or m.vel != 0.0)]
        for m in self.motors.values():
            if m not in busy:
                m.step(0.0)
        if not busy or dt_total <= 0:
            return
        n = max(1, math.ceil(dt_total / _MAX_STEP))
        dt = dt_total / n
        for _ in range(n):
            for m in busy:
                m.step(dt)

    def execute(self, line: str) -> bytes:
        """Run one command line; return the reply bytes (lines + ACK, or BELL ERRnnn CR)."""
        with self._lock:
            self._advance()
            out: list[str] = []
            try:
                self._execute(line.upper().replace(" ", "").replace("\t", ""), out)
            except _CmdError as exc:
                return "".join(s + "\r" for s in out).encode() + \
                    f"\x07ERR{exc.code:03d}\r".encode()
            return "".join(s + "\r" for s in out).encode() + b"\x06"

    def _execute(self, s: str, out: list[str]) -> None:
        addressed = 1
        i, n = 0, len(s)
        while i < n:
            c = s[i]
            if c == "#":
                m = _RE_MOTOR.match(s, i)
                if not m or not 1 <= int(m.group(1)) <= 32:
                    raise _CmdError(3)
                addressed, i = int(m.group(1)), m.end()
                continue
            if c == "I":
                i = self._ivar(s, i, out)
                continue
            if s.startswith("VER", i):
                out.append("1.947    01/07/2013")
                i += 3
                continue
            if s.startswith("TYPE", i):
                out.append("TURBO2")
                i += 4
                continue
            mot = self.motors.get(addressed)
            if s.startswith("HMZ", i):
                i += 3
                if mot:
                    mot.home_zero()
            elif s.startswith("HM", i):
                i += 2
                if mot:
                    mot.home()
            elif c == "J" and i + 1 < n and s[i + 1] in "/+-=":
                op, i = s[i + 1], i + 2
                if op == "=":
                    m = _RE_NUM.match(s, i)
                    if m is None:
                        raise _CmdError(3)
                    i = m.end()
                    if mot:
                        mot.jog(float(m.group(0)))
                elif mot and op == "/":
                    mot.enable()
                elif mot:
                    mot.jog(math.copysign(1e12, 1.0 if op == "+" else -1.0))
            elif c == "K":
                i += 1
                if mot:
                    mot.kill()
            elif c in "PVF?":
                i += 1
                out.append(self._query(mot, c))
            else:
                raise _CmdError(3)

    def _query(self, mot: MotorSim | None, c: str) -> str:
        if mot is None:
            return "000000000000" if c == "?" else "0"
        if c == "P":
            return _fmt(round(mot.actual - mot.ref, 4))
        if c == "V":
            period = self.globals[10] / 8388608.0 * 1e-3
            return _fmt(round(mot.vel * period if mot.closed_loop else 0.0, 4))
        if c == "F":
            return _fmt(round(mot.following_error, 4))
        return mot.status().hex()

    def _ivar(self, s: str, i: int, out: list[str]) -> int:
        m = _RE_IVAR.match(s, i)
        if m is None:
            raise _CmdError(3)
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) else first
        if not 0 <= first <= last <= 8191:
            raise _CmdError(3)
        if m.group(3) is not None:
            self._set_ivar(first, float(m.group(3)))
        else:
            out.extend(_fmt(self._get_ivar(k)) for k in range(first, last + 1))
        return m.end()

    def _get_ivar(self, k: int) -> float:
        mot = self.motors.get(k // 100) if 100 <= k < 3300 else None
        if mot is not None:
            return mot.ivars.get(k % 100, 0.0)
        return self.globals.get(k, 0.0)

    def _set_ivar(self, k: int, v: float) -> None:
        mot = self.motors.get(k // 100) if 100 <= k < 3300 else None
        if mot is not None:
            mot.ivars[k % 100] = v
        else:
            self.globals[k] = v

    # -- serial (RS-232 on a pseudo-terminal) -----------------------------------------------
    def serve_pty(self) -> str:
        """Also answer the serial protocol (command + CR in; lines + ACK, or BELL ERRnnn CR
        out, as with I3=2, I6=1) on a new pseudo-terminal; returns its path."""
        import os
        import pty
        import tty
        master, slave = pty.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        t = threading.Thread(target=self._serve_serial, args=(master, slave), daemon=True,
                             name="pmac-emu-pty")
        self._running.set()
        t.start()
        self._threads.append(t)
        return path

    def _serve_serial(self, master: int, slave: int) -> None:
        import os
        import select
        line = b""
        try:
            while self._running.is_set():
                if not select.select([master], [], [], 0.1)[0]:
                    continue
                for byte in os.read(master, 1024):
                    if byte != proto.CR:
                        line += bytes([byte])
                        continue
                    self.requests += 1
                    if self.mute:
                        line = b""
                        continue
                    try:
                        text = line.decode("ascii")
                        reply = self.execute(text) if text.isprintable() else b"\x07ERR004\r"
                    except UnicodeDecodeError:
                        reply = b"\x07ERR004\r"
                    line = b""
                    os.write(master, reply)
        except OSError:
            return
        finally:
            os.close(master)
            os.close(slave)

    # -- network --------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        assert self._server is not None
        while self._running.is_set():
            try:
                conn, _ = self._server.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            if self.refuse:
                conn.close()
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conns.add(conn)
            t = threading.Thread(target=self._serve, args=(conn,), name="pmac-emu-conn",
                                 daemon=True)
            t.start()
            self._threads = [x for x in self._threads if x.is_alive()] + [t]

    def _serve(self, conn: socket.socket) -> None:
        pending = b""
        try:
            while self._running.is_set():
                raw = _recv_exact(conn, proto.HEADER_SIZE)
                if raw is None:
                    return
                h = proto.decode_header(raw)
                data = b""
                if h.request_type == proto.VR_DOWNLOAD and h.length:
                    data = _recv_exact(conn, h.length)
                    if data is None:
                        return
                self.requests += 1
                if self.mute:
                    continue
                if h.request == proto.Request.GETRESPONSE and h.request_type == proto.VR_DOWNLOAD:
                    try:
                        text = data.decode("ascii")
                    except UnicodeDecodeError:
                        reply = b"\x07ERR004\r"
                    else:
                        if any(not 0x20 <= ord(ch) < 0x7F for ch in text):
                            reply = b"\x07ERR004\r"
                        else:
                            reply = self.execute(text)
                    pending = reply[proto.REPLY_CHUNK:]
                    conn.sendall(reply[:proto.REPLY_CHUNK])
                elif h.request == proto.Request.GETBUFFER:
                    chunk, pending = pending[:proto.REPLY_CHUNK], pending[proto.REPLY_CHUNK:]
                    conn.sendall(chunk or b"\x06")
                elif h.request == proto.Request.FLUSH:
                    pending = b""
                    conn.sendall(proto.FLUSH_REPLY)
                elif h.request == proto.Request.READREADY:
                    conn.sendall(bytes([1 if pending else 0, 0]))
                # other requests: not emulated, no answer (the client times out)
        except OSError:
            return
        finally:
            with self._lock:
                self._conns.discard(conn)
            conn.close()


def _recv_exact(conn: socket.socket, n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        try:
            chunk = conn.recv(n - len(buf))
        except OSError:
            return None
        if not chunk:
            return None
        buf += chunk
    return buf


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="pmac_emulator",
        description="Turbo PMAC emulator on 127.0.0.1 speaking the Ethernet protocol "
                    "(VR_PMAC_GETRESPONSE, FLUSH, GETBUFFER, READREADY).")
    ap.add_argument("--port", type=int, default=1025,
                    help="TCP port on 127.0.0.1 (0 = a free one; default 1025)")
    ap.add_argument("--motors", type=int, default=1, help="number of motors (default 1)")
    ap.add_argument("--start-position", type=float, default=0.0,
                    help="physical power-on position of every motor, counts (default 0)")
    ap.add_argument("--home-switch", type=float, default=0.0,
                    help="physical position of the home switch, counts (default 0)")
    ap.add_argument("--limits", type=float, nargs=2, default=(-320000.0, 320000.0),
                    metavar=("NEG", "POS"),
                    help="physical overtravel switch positions, counts "
                         "(default -320000 320000 = ±1.6 m at 200000 counts/m)")
    ap.add_argument("--home-speed", type=float, default=-32.0, metavar="COUNTS_PER_MS",
                    help="Ixx23 of every motor: home search speed, sign = direction "
                         "(default -32: toward the negative end)")
    ap.add_argument("--drop-every", type=float, default=0.0, metavar="S",
                    help="drop all client connections every S seconds (0 = never)")
    args = ap.parse_args(argv)
    try:
        emu = PmacEmulator(args.port, args.motors, args.start_position, args.home_switch,
                           tuple(args.limits))
        for m in emu.motors.values():
            m.ivars[23] = args.home_speed
        emu.start()
    except (ValueError, OSError) as exc:
        print(f"pmac_emulator: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    # SIGINT explicitly too: a process started from a background job inherits SIGINT
    # ignored, and Python then installs no KeyboardInterrupt handler. Installed before the
    # "listening" line, which callers wait for.
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    print(f"pmac_emulator: listening on 127.0.0.1:{emu.port} with {args.motors} motor(s)",
          flush=True)
    try:
        while not stop.wait(args.drop_every or 0.5):
            if args.drop_every:
                emu.drop_connections()
                print("pmac_emulator: dropped all connections", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
