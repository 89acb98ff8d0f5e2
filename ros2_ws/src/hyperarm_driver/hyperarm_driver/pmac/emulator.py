"""pmac_emulator: a Turbo PMAC on 127.0.0.1 speaking the Ethernet protocol (for tests and demos).

What it implements (Turbo PMAC Software Reference; Turbo PMAC User Manual, "Writing a Host
Communications Program"; the full list, and what is *not* implemented, is in docs/pmac.md):

- per motor: jog motion with a trapezoidal profile: ``J=`` (to position), ``J^`` (relative
  to the actual position), ``J:`` (relative to the commanded position), ``J+``/``J-``,
  ``J/`` (stop and hold; closes the loop), ``K`` (kill), speed Ixx22 (counts/ms),
  acceleration Ixx19 (counts/ms²) limited by Ixx20 (ms); soft limits Ixx13/Ixx14; every jog
  closes the loop of a killed motor, as on the card;
- home search ``HM`` (Ixx23, Ixx26, switch at a physical position) and ``HMZ``;
- hardware overtravel switches; following error = servo lag x velocity + an injectable
  disturbance; fatal (Ixx11) kills the motor, warning (Ixx12) is flagged; amplifier fault;
- queries ``P`` ``V`` ``F`` ``?``; variables ``P``/``Q``/``M``/``I`` read, written (with
  expressions: ``P1=P1+1``), ranges ``P1..3`` (one value per line), hex constants
  ``$20000``; I-variables keep the card's ranges (``I3=5`` keeps the low 2 bits: 1) and
  address I-variables reply in hex while I9 has bit 1 set; ``Isx11``/``Isx12`` count down
  every servo cycle (PLC timers); M-variable definitions ``Mn->...`` are stored, not mapped;
- ``VER``/``VERSION`` (version only), ``DATE``, ``CID``, ``TYPE``, ``SAVE`` (acknowledged),
  ``&n`` (coordinate system), ``%``/``%n`` (feed-rate override, stored per coordinate
  system), ``OPEN PLC n [CLEAR]`` ... ``CLOSE``, ``ENABLE PLC n``, ``DISABLE PLC n``,
  ``LIST PLC n``; PLC programs in the subset of :mod:`.plc`, scanned every millisecond;
- ``??`` (coordinate-system status, 18 hex digits) and ``???`` (global status, 12);
- replies framed by I3 (0..3) and I6 (0..3) as the card does; ``ERR003`` for anything
  else, ``ERR004`` for non-ASCII bytes; FLUSH answered with one byte (``<CTRL-X>`` with
  I63=1, else ``@``); ``<STX>message<CR>`` lines for unsolicited messages while I64=1;
- link faults for tests: :meth:`PmacEmulator.drop_connections`, ``mute`` (no answers, no
  execution: a cut cable), ``refuse`` (connections closed at once), ``busy`` (the next n
  commands answer NUL: busy, not executed);
- optionally the RS-232 protocol on a pseudo-terminal (:meth:`PmacEmulator.serve_pty`).

Command line: ``pmac_emulator --port 0`` prints ``pmac_emulator: listening on 127.0.0.1:PORT``.
Only 127.0.0.1 is ever bound.
"""
from __future__ import annotations

import argparse
import collections
import math
import re
import signal
import socket
import sys
import threading
import time
from dataclasses import dataclass, field

from . import plc as plclang
from . import protocol as proto
from .axis import I10_DEFAULT, MotorStatus

__all__ = ["PmacEmulator", "MotorSim", "main", "VERSION", "DATE", "CID"]

VERSION = "1.947"                 # firmware version (VER answers this only)
DATE = "01/07/2013"               # firmware date (DATE)
CID = 603382                      # card ID (CID): a 3U Turbo PMAC2 with Ethernet (Geo Brick)
_MAX_STEP = 1e-3   # s, integration step and PLC scan period
_LAG = 0.002       # s, servo lag: following error = lag * velocity

# Turbo PMAC factory defaults of the motor I-variables the emulator uses.
_MOTOR_DEFAULTS = {0: 1.0, 11: 32000.0, 12: 16000.0, 13: 0.0, 14: 0.0, 19: 0.015625,
                   20: 250.0, 21: 50.0, 22: 32.0, 23: 32.0, 26: 0.0, 28: 160.0}
# Motor I-variables holding addresses (reported in hex while I9 bit 1 is set).
_MOTOR_ADDRESS_IVARS = (1, 2, 3, 4, 5, 10, 24, 25, 42, 43, 81, 82, 83, 91)
_GLOBAL_ADDRESS_IVARS = (20, 21, 22, 23, 24)
# Integer I-variables with a range 0..2**bits-1. Turbo PMAC User Manual, "Limited Range": "an
# attempt to assign an out-of-range value does not cause an error. The value is automatically
# rolled over to within the range by modulo arithmetic (truncation)": I3=5 gives 5 mod 4 = 1.
_GLOBAL_BITS = {3: 2, 6: 2, 9: 2, 63: 1, 64: 1}
_MOTOR_BITS = {0: 1}
_RE_VAR = re.compile(r"([PQMI])(\d+)")
_RE_INT = re.compile(r"\d+")
# Status bits an M-variable can read without building the whole status (same as status()).
_FAST_BITS = {("Y", 2): lambda m: m.fatal_fe, ("Y", 3): lambda m: m.amp_fault,
              ("Y", 10): lambda m: m.homed, ("X", 19): lambda m: m.closed_loop,
              ("X", 18): lambda m: not m.closed_loop}
_RE_STATUS_MDEF = re.compile(r"([XY]):\$?([0-9A-F]+),(\d+)(?:,1)?")
_RE_MDEF = re.compile(r"\*|[XYDLF]:\$?[0-9A-F]+(?:,\d+)*(?:,[SU])?")


class _CmdError(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


def _fmt(x: float) -> str:
    """A value as the card prints it: decimal, no exponent, no trailing zeros."""
    if float(x).is_integer():
        return str(int(x))
    return f"{x:.10f}".rstrip("0").rstrip(".")


def _motor_address_defaults(m: int) -> dict[int, float]:
    base = 0x078000 + ((m - 1) // 4) * 0x100 + ((m - 1) % 4) * 8
    ect = 0x003501 + (m - 1)
    return {1: base + 1, 2: base + 2, 3: ect, 4: ect, 5: 0x0035C0, 10: 0, 24: 0x800001,
            25: base, 42: base, 43: base, 81: 0, 82: 0, 83: base + 1, 91: 0}


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
    enables: int = 0                # times the loop was closed (J/, a jog, HM on a killed motor)
    prejog: float = 0.0             # counts, where the last jog started (J= alone)
    ivars: dict[int, float] = field(default_factory=lambda: dict(_MOTOR_DEFAULTS))
    now: float = 0.0                # s, simulated time of the last step (emulator clock)
    motion_ended_at: float = math.nan   # s, when the motor last came to rest (or was killed)

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
        if self.vel != 0.0 or self.mode != "idle":
            self.motion_ended_at = self.now
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
            self.enables += 1
            self.vel = 0.0
            self.mode = "idle"
            self._check_following_error()
            return
        if self.mode != "idle":
            v, a = self._speed_accel()
            stop = self.vel * abs(self.vel) / (2 * a)
            self.mode, self.target = "jog", self.pos + stop

    def jog(self, target_counts: float) -> None:
        """Jog to a position in motor counts (relative to the motor zero).

        Like every jog command on the card, this closes the loop of a killed motor first
        (PMAC Software Reference, O{constant}: "Closed-loop control for the motor can be
        re-established with the J command"). The rail driver therefore never sends a jog to
        a motor it has not enabled itself; see driver.py and watchdog.py.
        """
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
    def step(self, dt: float, now: float) -> None:
        self.now = now
        moving = self.vel != 0.0 or self.mode != "idle"
        self._step(dt)
        if moving and self.vel == 0.0 and self.mode == "idle":
            self.motion_ended_at = now

    def _step(self, dt: float) -> None:
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


@dataclass
class _Port:
    """What the card keeps per communication port: addressed motor and coordinate system,
    the open program buffer, and (Ethernet) the rest of a long reply."""

    motor: int = 1
    cs: int = 1
    open_plc: plclang.PlcProgram | None = None
    pending: bytes = b""


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
        # I3=2, I6=1: set up for a host program, as the driver and dls-pmaclib set them
        self.globals: dict[int, float] = {10: float(i10), 3: 2.0, 6: 1.0, 9: 2.0, 63: 1.0,
                                          64: 0.0, 20: 0.0, 21: 0.0, 22: 0.0, 23: 0.0,
                                          24: 0x060000}
        self.motors = {m: MotorSim(m, pos=float(start_position), home_at=float(home_switch),
                                   neg_limit_at=float(limits[0]), pos_limit_at=float(limits[1]))
                       for m in range(1, motors + 1)}
        for m in self.motors.values():
            m.ivars.update(_motor_address_defaults(m.number))
        self.pvars: dict[int, float] = {}
        self.qvars: dict[int, dict[int, float]] = {}
        self.mvars: dict[int, float] = {}
        self.mdefs: dict[int, str] = {}
        self.feedrate: dict[int, float] = {}
        self.plcs: dict[int, plclang.PlcProgram] = {}
        self._timers: dict[int, tuple[float, float]] = {}   # I5s11/I5s12: (value, set at)
        self._messages: list[str] = []
        self._internal = _Port()      # execute() without a port (tests, the API)
        self._plc_port = _Port()      # CMD"..." of PLC programs
        self._lock = threading.RLock()
        self._t0 = time.monotonic()
        self._t = self._t0            # simulated time (monotonic clock), advanced lazily
        self._server: socket.socket | None = None
        self._conns: set[socket.socket] = set()
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self.mute = False      # read requests, never answer nor execute (a cut cable)
        self.refuse = False    # close new connections at once
        self.busy = 0          # answer the next n command lines with NUL (busy, not run)
        self.requests = 0
        # the last command lines received from a port, in order (for tests and debugging),
        # and when each was taken (time.monotonic(), for the heartbeat benchmark)
        self.log: collections.deque[str] = collections.deque(maxlen=10000)
        self.log_times: collections.deque[float] = collections.deque(maxlen=10000)

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
        for target, name in ((self._accept_loop, "pmac-emu-accept"),
                             (self._tick_loop, "pmac-emu-tick")):
            t = threading.Thread(target=target, name=name, daemon=True)
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
    @property
    def now(self) -> float:
        """The emulator's clock (time.monotonic() of the simulated present), after advancing."""
        with self._lock:
            self._advance()
            return self._t

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
            self._scan_plcs()

    def set_disturbance(self, n: int, counts: float) -> None:
        """Extra following error (counts) while the loop is closed, e.g. a jammed carriage."""
        with self._lock:
            self._advance()
            m = self.motors[n]
            m.disturbance = float(counts)
            m._check_following_error()
            self._scan_plcs()

    def _scan_plcs(self) -> None:
        """One scan of every enabled PLC now (after an injected fault: on the card the PLCs
        see it at their next scan, within the emulator's 1 ms step anyway)."""
        for p in self.plcs.values():
            if p.enabled and p.ops:
                p.scan(self, self._plc_command)

    def send_message(self, text: str) -> None:
        """An unsolicited message line (as from a PLC SEND): sent before the next reply,
        tagged ``<STX>text<CR>`` while I64=1 (Turbo PMAC Software Reference, I64)."""
        with self._lock:
            self._messages.append(text)

    # -- simulation -----------------------------------------------------------------------
    @property
    def servo_period(self) -> float:
        return self.globals[10] / 8388608.0 * 1e-3

    def _tick_loop(self) -> None:
        while self._running.is_set():
            time.sleep(0.005)
            with self._lock:
                self._advance()

    def _advance(self) -> None:
        now = time.monotonic()
        dt_total = now - self._t
        if dt_total <= 0:
            return
        plcs = [p for p in self.plcs.values() if p.enabled and p.ops]
        busy = [m for m in self.motors.values() if m.closed_loop and
                (m.mode != "idle" or m.vel != 0.0)]
        if not busy and not plcs:
            self._t = now
            for m in self.motors.values():
                m.step(0.0, now)
            return
        n = max(1, math.ceil(dt_total / _MAX_STEP))
        dt = dt_total / n
        for _ in range(n):
            self._t += dt
            for m in self.motors.values():
                m.step(dt, self._t)
            for p in plcs:
                if p.enabled:
                    p.scan(self, self._plc_command)
        self._t = now

    def _plc_command(self, text: str) -> None:
        """A CMD"..." of a PLC program: an on-line command from the card itself."""
        try:
            self._execute(plclang.squeeze(text), [], self._plc_port)
        except (_CmdError, plclang.PlcSyntaxError):
            pass

    # -- variables (the VarStore of the PLC interpreter) ----------------------------------
    def get(self, kind: str, n: int) -> float:
        if kind == "P":
            return self.pvars.get(n, 0.0)
        if kind == "Q":
            return self.qvars.get(self._internal.cs, {}).get(n, 0.0)
        if kind == "M":
            return self._get_mvar(n)
        return self._get_ivar(n)

    def set(self, kind: str, n: int, value: float) -> None:
        if kind == "P":
            self.pvars[n] = value
        elif kind == "Q":
            self.qvars.setdefault(self._internal.cs, {})[n] = value
        elif kind == "M":
            self.mvars[n] = value
        else:
            self._set_ivar(n, value)

    def _get_mvar(self, n: int) -> float:
        """An M-variable: the motor status bit it is defined to (Turbo PMAC suggested
        M-variables: motor xx status words at X:$0000B0 and Y:$0000C0 + (xx-1)*$80, bits as
        in the ``#n?`` reply), else its stored value."""
        d = _RE_STATUS_MDEF.fullmatch(self.mdefs.get(n, ""))
        if d is not None:
            space, addr, bit = d.group(1), int(d.group(2), 16), int(d.group(3))
            base = 0xB0 if space == "X" else 0xC0
            k, off = divmod(addr - base, 0x80)
            mot = self.motors.get(k + 1)
            if off == 0 and mot is not None and 0 <= bit < 24:
                fast = _FAST_BITS.get((space, bit))     # (PLC scans read these every ms)
                if fast is not None:
                    return float(bool(fast(mot)))
                st = mot.status()
                return float((st.word1 if space == "X" else st.word2) >> bit & 1)
        return self.mvars.get(n, 0.0)

    def _get_ivar(self, k: int) -> float:
        if _is_timer(k):
            # Software Reference, Isx11: "count down one unit per servo cycle ... until it
            # reaches its maximum negative value of -8,388,608. It will not roll over."
            value, at = self._timers.get(k, (0.0, self._t))
            return float(max(-8388608, value - math.floor((self._t - at) / self.servo_period)))
        mot = self.motors.get(k // 100) if 100 <= k < 3300 else None
        if mot is not None:
            return mot.ivars.get(k % 100, 0.0)
        return self.globals.get(k, 0.0)

    def _set_ivar(self, k: int, v: float) -> None:
        if _is_timer(k):
            self._timers[k] = (float(int(v)), self._t)     # a signed 24-bit integer
            return
        mot = self.motors.get(k // 100) if 100 <= k < 3300 else None
        bits = _MOTOR_BITS.get(k % 100) if mot is not None else _GLOBAL_BITS.get(k)
        if bits is not None:
            v = float(int(v) & ((1 << bits) - 1))
        if mot is not None:
            mot.ivars[k % 100] = v
        else:
            self.globals[k] = v

    def _format_ivar(self, k: int) -> str:
        value = self._get_ivar(k)
        is_addr = (k % 100 in _MOTOR_ADDRESS_IVARS if 100 <= k < 3300
                   else k in _GLOBAL_ADDRESS_IVARS)
        if is_addr and int(self.globals[9]) & 2:
            return f"${int(value):X}"
        return _fmt(value)

    # -- command interpreter --------------------------------------------------------------
    def execute(self, line: str, port: _Port | None = None) -> bytes:
        """Run one command line; return the reply bytes, framed by I3 and I6."""
        with self._lock:
            self._advance()
            port = port or self._internal
            out: list[str] = []
            error = None
            try:
                self._execute(plclang.squeeze(line), out, port)
            except _CmdError as exc:
                error = exc.code
            except plclang.PlcSyntaxError:
                error = 3
            return self._frame(out, error)

    def _frame(self, out: list[str], error: int | None) -> bytes:
        """Turbo PMAC Software Reference, I3 (handshake) and I6 (error reporting)."""
        i3, i6 = int(self.globals[3]), int(self.globals[6])
        lf = "\n" if i3 in (1, 3) else ""
        body = "".join(f"{lf}{s}\r" for s in out).encode()
        if error is not None:
            return body + (f"\x07ERR{error:03d}\r".encode() if i6 in (1, 3) else b"\x07")
        return body + {0: b"", 1: b"\n"}.get(i3, b"\x06")

    def _take_messages(self) -> bytes:
        with self._lock:
            msgs, self._messages = self._messages, []
            tag = b"\x02" if int(self.globals[64]) else b""
        return b"".join(tag + m.encode() + b"\r" for m in msgs)

    def _execute(self, s: str, out: list[str], port: _Port) -> None:
        if port.open_plc is not None and s not in ("CLOSE",):
            try:
                port.open_plc.add_line(s)
            except plclang.PlcSyntaxError:
                raise _CmdError(3) from None
            return
        i, n = 0, len(s)
        while i < n:
            i = self._one(s, i, out, port)

    def _one(self, s: str, i: int, out: list[str], port: _Port) -> int:
        c = s[i]
        if c in "#&":
            m = _RE_INT.match(s, i + 1)
            if m is None:
                out.append(f"{c}{port.motor if c == '#' else port.cs}")
                return i + 1
            k = int(m.group(0))
            if c == "#":
                if not 1 <= k <= 32:
                    raise _CmdError(3)
                port.motor = k
            else:
                if not 1 <= k <= 16:
                    raise _CmdError(3)
                port.cs = k
            return m.end()
        if c == "%":
            if i + 1 < len(s) and (s[i + 1].isdigit() or s[i + 1] in ".$"):
                value, end = plclang.parse_constant(s, i + 1)
                self.feedrate[port.cs] = value
                return end
            out.append(_fmt(self.feedrate.get(port.cs, 100.0)))
            return i + 1
        for word, reply in (("VERSION", VERSION), ("VER", VERSION), ("DATE", DATE),
                            ("CID", str(CID)), ("TYPE", "TURBO2")):
            if s.startswith(word, i):
                out.append(reply)
                return i + len(word)
        if s.startswith("SAVE", i):
            return i + 4                         # acknowledged; nothing to write to flash
        if s.startswith("CLOSE", i):
            if port.open_plc is not None:
                try:
                    port.open_plc.check_structure()
                except plclang.PlcSyntaxError:
                    port.open_plc = None
                    raise _CmdError(9) from None
            port.open_plc = None
            return i + 5
        for word in ("OPENPLC", "LISTPLC", "ENABLEPLC", "ENAPLC", "DISABLEPLC", "DISPLC"):
            if s.startswith(word, i):
                m = _RE_INT.match(s, i + len(word))
                if m is None or not 0 <= int(m.group(0)) <= 31:
                    raise _CmdError(3)
                return self._plc_command_word(word, int(m.group(0)), s, m.end(), out, port)
        if s.startswith("???", i):
            out.append(self._global_status())
            return i + 3
        if s.startswith("??", i):
            out.append(self._cs_status(port.cs))
            return i + 2
        if c in "PQMI" and i + 1 < len(s) and s[i + 1].isdigit():
            return self._variable(s, i, out, port)
        return self._motor_command(s, i, out, port)

    def _cs_status(self, cs: int) -> str:
        """``??``: the addressed coordinate system's three 24-bit status words, 18 hex
        digits (Turbo PMAC Software Reference, ``??``). The emulator runs no motion program
        and has no axis definitions, so no motor belongs to a coordinate system: no program
        running, LINEAR move mode, none of the per-motor fault or in-position summaries
        (word 2 bits 20, 19, 18, 17 describe motors *in* the coordinate system): all 0."""
        if not 1 <= cs <= 16:
            raise _CmdError(3)
        return "0" * 18

    def _global_status(self) -> str:
        """``???``: the two 24-bit global status words (X:$000006, Y:$000006), 12 hex
        digits (Turbo PMAC Software Reference, ``???``): no servo error, no real-time
        interrupt re-entry, no configuration or phase-clock error, no data gathering: 0."""
        return "0" * 12

    def _plc_command_word(self, word: str, k: int, s: str, i: int, out: list[str],
                          port: _Port) -> int:
        if word == "OPENPLC":
            prog = self.plcs.setdefault(k, plclang.PlcProgram(k))
            prog.enabled = False               # the card stops a PLC opened for editing
            if s.startswith("CLEAR", i):
                prog.clear()
                i += 5
            port.open_plc = prog
        elif word == "LISTPLC":
            out.extend(self.plcs[k].lines if k in self.plcs else [])
        elif word in ("ENABLEPLC", "ENAPLC"):
            if k in self.plcs:
                self.plcs[k].enabled = True
        elif k in self.plcs:
            self.plcs[k].enabled = False
        return i

    def _variable(self, s: str, i: int, out: list[str], port: _Port) -> int:
        m = _RE_VAR.match(s, i)
        kind, first = m.group(1), int(m.group(2))
        if first > plclang.VAR_MAX:
            raise _CmdError(3)
        j = m.end()
        store = _PortVars(self, port)
        if s.startswith("..", j):
            m2 = _RE_INT.match(s, j + 2)
            if m2 is None or not first <= int(m2.group(0)) <= plclang.VAR_MAX:
                raise _CmdError(3)
            for k in range(first, int(m2.group(0)) + 1):
                out.append(self._format_ivar(k) if kind == "I" else _fmt(store.get(kind, k)))
            return m2.end()
        if kind == "M" and s.startswith("->", j):
            j += 2
            d = _RE_MDEF.match(s, j)
            if d is None:
                out.append(self.mdefs.get(first, "*"))
                return j
            self.mdefs[first] = d.group(0)
            return d.end()
        if s.startswith("=", j):
            expr, end = plclang.parse_expression(s, j + 1)
            store.set(kind, first, expr(store))
            return end
        out.append(self._format_ivar(first) if kind == "I" else _fmt(store.get(kind, first)))
        return j

    def _motor_command(self, s: str, i: int, out: list[str], port: _Port) -> int:
        mot = self.motors.get(port.motor)
        c = s[i]
        if mot is not None and not mot.ivars[0] and c not in "PVF?":
            mot = None           # Ixx00=0: a deactivated motor takes no motion command
        if s.startswith("HMZ", i):
            if mot:
                mot.home_zero()
            return i + 3
        if s.startswith("HM", i):
            if mot:
                mot.home()
            return i + 2
        if c == "J" and i + 1 < len(s) and s[i + 1] in "/+-=^:":
            op, i = s[i + 1], i + 2
            here = (mot.target if mot.mode == "jog" else mot.pos) - mot.ref if mot else 0.0
            if op in "=^:":
                if op == "=" and (i >= len(s) or not (s[i].isdigit() or s[i] in "+-.$")):
                    if mot:
                        mot.jog(mot.prejog)          # J= alone: back to the pre-jog position
                    return i
                value, i = plclang.parse_constant(s, i)
                if mot:
                    if op == "=":
                        goal = value
                    elif op == "^":
                        goal = mot.actual - mot.ref + value
                    else:
                        base = mot.target if mot.mode == "jog" else mot.pos
                        goal = base - mot.ref + value
                    mot.prejog = here
                    mot.jog(goal)
            elif mot and op == "/":
                mot.enable()
            elif mot:
                mot.prejog = here
                mot.jog(math.copysign(1e12, 1.0 if op == "+" else -1.0))
            return i
        if c == "K":
            if mot:
                mot.kill()
            return i + 1
        if c in "PVF?":
            out.append(self._query(mot, c))
            return i + 1
        raise _CmdError(3)

    def _query(self, mot: MotorSim | None, c: str) -> str:
        if mot is None:
            return "000000000000" if c == "?" else "0"
        if c == "P":
            return _fmt(round(mot.actual - mot.ref, 4))
        if c == "V":
            return _fmt(round(mot.vel * self.servo_period if mot.closed_loop else 0.0, 4))
        if c == "F":
            return _fmt(round(mot.following_error, 4))
        return mot.status().hex()

    # -- serial (RS-232 on a pseudo-terminal) -----------------------------------------------
    def serve_pty(self) -> str:
        """Also answer the serial protocol (command + CR in; the reply framed by I3/I6 out)
        on a new pseudo-terminal; returns its path."""
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
        port = _Port()
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
                    reply = self._run_line(line, port)
                    line = b""
                    os.write(master, reply)
        except OSError:
            return
        finally:
            os.close(master)
            os.close(slave)

    def _run_line(self, data: bytes, port: _Port) -> bytes:
        """One command line from a port: ERR004 for non-ASCII, NUL while busy."""
        if self.busy > 0:
            self.busy -= 1
            return b"\x00"
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError:
            return self._frame([], 4)
        if any(not 0x20 <= ord(ch) < 0x7F for ch in text):
            return self._frame([], 4)
        with self._lock:
            self.log.append(text)
            self.log_times.append(time.monotonic())
        return self.execute(text, port)

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
        port = _Port()
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
                    reply = self._run_line(data, port)
                    messages = self._take_messages()
                    if messages and int(self.globals[64]):
                        # Ethernet protocol: after <STX> only the data up to the next <CR>
                        # is returned; the rest waits for VR_PMAC_GETBUFFER.
                        port.pending = reply
                        conn.sendall(messages)
                        continue
                    reply = messages + reply
                    port.pending = reply[proto.REPLY_CHUNK:]
                    conn.sendall(reply[:proto.REPLY_CHUNK])
                elif h.request == proto.Request.GETBUFFER:
                    chunk, port.pending = (port.pending[:proto.REPLY_CHUNK],
                                           port.pending[proto.REPLY_CHUNK:])
                    conn.sendall(chunk or b"\x06")
                elif h.request == proto.Request.FLUSH:
                    port.pending = b""
                    # one byte: the <CTRL-X> echo with I63=1 (Software Reference, I63)
                    conn.sendall(b"\x18" if int(self.globals[63]) else proto.FLUSH_REPLY)
                elif h.request == proto.Request.READREADY:
                    conn.sendall(bytes([1 if port.pending else 0, 0]))
                # other requests: not emulated, no answer (the client times out)
        except OSError:
            return
        finally:
            with self._lock:
                self._conns.discard(conn)
            conn.close()


class _PortVars:
    """The variables as seen from one port (Q-variables of its addressed coordinate system)."""

    def __init__(self, emu: PmacEmulator, port: _Port) -> None:
        self.emu, self.port = emu, port

    def get(self, kind: str, n: int) -> float:
        if kind == "Q":
            return self.emu.qvars.get(self.port.cs, {}).get(n, 0.0)
        return self.emu.get(kind, n)

    def set(self, kind: str, n: int, value: float) -> None:
        if kind == "Q":
            self.emu.qvars.setdefault(self.port.cs, {})[n] = value
        else:
            self.emu.set(kind, n, value)


def _is_timer(k: int) -> bool:
    """Isx11, Isx12 (s = 1..16): coordinate-system countdown timers, in servo cycles."""
    return 5100 <= k <= 6699 and k % 100 in (11, 12)


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
