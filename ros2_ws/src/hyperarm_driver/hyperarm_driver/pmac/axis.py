"""One Turbo PMAC motor as the hyperarm rail: SI units, soft limits, status decode.

Units: the card works in encoder counts and milliseconds (Ixx22 counts/ms, Ixx19
counts/ms², ``#nV`` counts per servo cycle); this module converts to metres and seconds with
``counts_per_metre`` from the description (``rail.pmac.counts_per_metre``) and the servo
period from I10. Every motion command is checked against the soft limits *before* it is
formatted, so a target outside ``[lower, upper]`` never reaches the card.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Protocol

from .protocol import format_constant, parse_number
from .errors import PmacProtocolError, RailCommandError, RailConfigError
from .watchdog import WatchdogConfig, download_lines

__all__ = ["MotorStatus", "RailConfig", "RailState", "RailAxis", "CommandPort",
           "I10_DEFAULT", "servo_period_from_i10"]

I10_DEFAULT = 3713991   # Turbo PMAC factory servo interrupt time: 0.442 ms


def servo_period_from_i10(i10: float) -> float:
    """Servo period (s) from I10 (units of 1/8388608 ms)."""
    if not i10 > 0:
        raise PmacProtocolError(f"I10 must be positive, got {i10}")
    return float(i10) / 8388608.0 * 1e-3


# (field, word, bit) of the two 24-bit status words of ``#n?`` (Turbo PMAC Software Ref.).
_BITS: tuple[tuple[str, int, int], ...] = (
    ("activated", 1, 23),
    ("neg_limit", 1, 22),
    ("pos_limit", 1, 21),
    ("amp_enabled", 1, 19),
    ("open_loop", 1, 18),
    ("move_timer", 1, 17),
    ("desired_velocity_zero", 1, 13),
    ("abort_decel", 1, 12),
    ("home_search", 1, 10),
    ("stopped_on_desired_limit", 2, 12),
    ("stopped_on_position_limit", 2, 11),
    ("home_complete", 2, 10),
    ("integrated_following_error", 2, 6),
    ("i2t_fault", 2, 5),
    ("amp_fault", 2, 3),
    ("fatal_following_error", 2, 2),
    ("warning_following_error", 2, 1),
    ("in_position", 2, 0),
)


@dataclass(frozen=True)
class MotorStatus:
    """The decoded ``#n?`` reply: two 24-bit words as 12 hex digits."""

    word1: int
    word2: int
    activated: bool = False
    neg_limit: bool = False
    pos_limit: bool = False
    amp_enabled: bool = False
    open_loop: bool = False
    move_timer: bool = False
    desired_velocity_zero: bool = False
    abort_decel: bool = False
    home_search: bool = False
    stopped_on_desired_limit: bool = False
    stopped_on_position_limit: bool = False
    home_complete: bool = False
    integrated_following_error: bool = False
    i2t_fault: bool = False
    amp_fault: bool = False
    fatal_following_error: bool = False
    warning_following_error: bool = False
    in_position: bool = False

    @classmethod
    def from_words(cls, word1: int, word2: int) -> "MotorStatus":
        for w in (word1, word2):
            if not 0 <= w < 1 << 24:
                raise PmacProtocolError(f"status word {w:#x} is not 24-bit")
        flags = {name: bool((word1 if word == 1 else word2) >> bit & 1)
                 for name, word, bit in _BITS}
        return cls(word1=word1, word2=word2, **flags)

    @classmethod
    def from_hex(cls, text: str) -> "MotorStatus":
        """Decode the 12 hex digits the card answers to ``#n?``."""
        t = text.strip()
        if len(t) != 12:
            raise PmacProtocolError(f"motor status must be 12 hex digits, got {text!r}")
        try:
            return cls.from_words(int(t[:6], 16), int(t[6:], 16))
        except ValueError:
            raise PmacProtocolError(f"motor status is not hex: {text!r}") from None

    @classmethod
    def from_flags(cls, **flags: bool) -> "MotorStatus":
        """Build from named flags (the emulator uses this to answer ``#n?``)."""
        known = {name for name, _, _ in _BITS}
        unknown = set(flags) - known
        if unknown:
            raise ValueError(f"unknown status flags {sorted(unknown)}")
        w = {1: 0, 2: 0}
        for name, word, bit in _BITS:
            if flags.get(name):
                w[word] |= 1 << bit
        return cls.from_words(w[1], w[2])

    def hex(self) -> str:
        return f"{self.word1:06X}{self.word2:06X}"

    @property
    def faults(self) -> list[str]:
        """Names of the fault conditions set (empty if none)."""
        return [f.name for f in fields(self) if f.name in (
            "amp_fault", "fatal_following_error", "i2t_fault", "integrated_following_error")
            and getattr(self, f.name)]


def _decimal(x: float) -> str:
    """``x`` as a plain decimal with up to 9 places (:func:`protocol.format_constant`: the
    card takes no exponent). RailCommandError if it would round to 0."""
    text = format_constant(x)
    if float(text) == 0.0:
        raise RailCommandError(f"value {x!r} too small for the card (rounds to 0)")
    return text


class CommandPort(Protocol):
    """What the axis needs from a client (PmacClient, PmacSerialClient)."""

    def command(self, command: str) -> list[str]: ...


@dataclass(frozen=True)
class RailConfig:
    """The rail axis: PMAC motor, scaling and limits (m, m/s, m/s²)."""

    motor: int
    counts_per_metre: float
    lower: float
    upper: float
    max_velocity: float
    max_acceleration: float

    def __post_init__(self) -> None:
        if not 1 <= int(self.motor) <= 32:
            raise RailConfigError(f"PMAC motor number must be 1..32, got {self.motor}")
        for name in ("counts_per_metre", "lower", "upper", "max_velocity", "max_acceleration"):
            if not math.isfinite(getattr(self, name)):
                raise RailConfigError(f"{name} must be finite, got {getattr(self, name)}")
        if self.counts_per_metre == 0:
            raise RailConfigError("counts_per_metre must be non-zero")
        if not self.lower < self.upper:
            raise RailConfigError(f"rail limits must satisfy lower < upper: "
                                  f"{self.lower} .. {self.upper}")
        if self.max_velocity <= 0 or self.max_acceleration <= 0:
            raise RailConfigError("max_velocity and max_acceleration must be positive")

    @classmethod
    def from_rail(cls, rail: object, motor: int = 0, counts_per_metre: float = 0.0
                  ) -> "RailConfig":
        """From a description RailSpec; non-zero ``motor``/``counts_per_metre`` override it."""
        return cls(motor=int(motor or getattr(rail, "pmac_motor")),
                   counts_per_metre=float(counts_per_metre or getattr(rail, "counts_per_metre")),
                   lower=float(getattr(rail, "lower")), upper=float(getattr(rail, "upper")),
                   max_velocity=float(getattr(rail, "velocity")),
                   max_acceleration=float(getattr(rail, "acceleration")))

    def to_counts(self, metres: float) -> float:
        return metres * self.counts_per_metre

    def to_metres(self, counts: float) -> float:
        return counts / self.counts_per_metre

    def check_position(self, metres: float) -> float:
        """The target as float if finite and within the soft limits, else RailCommandError."""
        try:
            x = float(metres)
        except (TypeError, ValueError):
            raise RailCommandError(f"rail setpoint {metres!r} is not a number") from None
        if not math.isfinite(x):
            raise RailCommandError(f"rail setpoint {x} is not finite")
        if not self.lower <= x <= self.upper:
            raise RailCommandError(f"rail setpoint {x:.4f} m outside the soft limits "
                                   f"[{self.lower:g}, {self.upper:g}] m")
        return x


@dataclass(frozen=True)
class RailState:
    """One poll of the axis (m, m/s, m) with the decoded status; ``armed`` is the safety
    PLC's armed flag (None without the PLC)."""

    position: float
    velocity: float
    following_error: float
    status: MotorStatus
    armed: bool | None = None


class RailAxis:
    """Commands for one PMAC motor, in metres. Blocking; errors from the client propagate.

    ``servo_period`` (s) converts ``#nV``; :meth:`configure` reads it from I10.
    ``watchdog``: the on-card safety PLC (:mod:`.watchdog`) that :meth:`configure`
    downloads and every poll feeds; None = no PLC (the card then finishes a jog on its own
    if the host goes away).
    """

    def __init__(self, port: CommandPort, config: RailConfig,
                 servo_period: float | None = None,
                 watchdog: WatchdogConfig | None = None) -> None:
        self.port = port
        self.config = config
        self.servo_period = servo_period or servo_period_from_i10(I10_DEFAULT)
        self.watchdog = watchdog
        # the safety PLC's armed flag read in the last jog's line (None: no PLC / no jog)
        self.last_jog_armed: bool | None = None
        m = config.motor
        self._poll = f"#{m}P#{m}V#{m}F#{m}?"
        if watchdog is not None:
            hb = f"P{watchdog.heartbeat}"
            self._poll = f"{hb}={hb}+1 {self._poll} P{watchdog.armed}"

    @property
    def motor(self) -> int:
        return self.config.motor

    def _ivar(self, n: int) -> str:
        return f"I{self.config.motor * 100 + n}"

    # -- setup ----------------------------------------------------------------------------
    def read_servo_period(self) -> float:
        lines = self.port.command("I10")
        self.servo_period = servo_period_from_i10(parse_number(lines, "I10"))
        return self.servo_period

    def set_communication(self) -> None:
        """``I3=2 I6=1 I64=1``: ACK-terminated replies with CR line ends, errors as
        ``ERRnnn`` (Software Reference, I3 and I6; public Turbo PMAC Ethernet drivers such as
        dls-pmaclib send the same at connect), and unsolicited messages (a PLC's ``SEND``)
        tagged ``<STX>text<CR>`` (I64), so they are told apart from command replies instead
        of corrupting one and looking like a link loss. Applies to this very command's
        reply."""
        self.port.command("I3=2 I6=1 I64=1")

    def check_communication(self) -> None:
        """Read I3, I6 and I64; RailConfigError unless I3 is 2 or 3, I6 is 1 or 3 and I64 is
        1 (a card at I3=1 already fails to answer in ACK framing: PmacProtocolError names
        it)."""
        lines = self.port.command("I3 I6 I64")
        if len(lines) != 3:
            raise PmacProtocolError(f"I3 I6 I64: expected three values, got {lines!r}")
        i3, i6, i64 = (parse_number([x], "I3/I6/I64") for x in lines)
        if i3 not in (2, 3) or i6 not in (1, 3) or i64 != 1:
            raise RailConfigError(f"the card has I3={i3:g}, I6={i6:g}, I64={i64:g}; the driver "
                                  "needs I3=2 (ACK replies), I6=1 (ERRnnn errors) and I64=1 "
                                  "(tagged unsolicited messages): set them on the card or let "
                                  "the driver configure it")

    def download_watchdog(self) -> None:
        """Download and enable the safety PLC (needs :attr:`servo_period` from I10)."""
        if self.watchdog is None:
            return
        for line in download_lines(self.watchdog, self.motor, self.servo_period):
            self.port.command(line)

    def configure(self, speed: float | None = None) -> None:
        """Set I3/I6; read I10; write jog speed/acceleration (Ixx22, Ixx19, Ixx20=0,
        Ixx21=0) and the soft limits Ixx13/Ixx14 (counts from home) from the config;
        download the safety PLC.

        ``speed`` (m/s) defaults to ``max_velocity``; it must be within (0, max_velocity].
        """
        c = self.config
        v = c.max_velocity if speed is None else float(speed)
        if not 0 < v <= c.max_velocity:
            raise RailCommandError(f"jog speed {v} m/s not within (0, {c.max_velocity:g}] m/s")
        self.set_communication()
        self.read_servo_period()
        cpm = abs(c.counts_per_metre)
        lo, hi = sorted((c.to_counts(c.lower), c.to_counts(c.upper)))
        # whole counts, rounded inwards; 0 would switch a soft limit off on the card, so a
        # limit at 0 is written as +1 / -1 count (Turbo PMAC Software Reference, Ixx13/14)
        pos_limit, neg_limit = math.floor(hi) or 1, math.ceil(lo) or -1
        self.port.command(
            f"{self._ivar(22)}={_decimal(v * cpm / 1e3)} "          # counts/ms
            f"{self._ivar(19)}={_decimal(c.max_acceleration * cpm / 1e6)} "   # counts/ms^2
            f"{self._ivar(20)}=0 {self._ivar(21)}=0 "
            f"{self._ivar(13)}={pos_limit} {self._ivar(14)}={neg_limit}")
        self.download_watchdog()

    def read_ivar(self, n: int) -> float:
        """Read motor I-variable Ixx{n} (n = 0..99)."""
        if not 0 <= n <= 99:
            raise RailCommandError(f"motor I-variable suffix must be 0..99, got {n}")
        return parse_number(self.port.command(self._ivar(n)), self._ivar(n))

    # -- state ----------------------------------------------------------------------------
    def read(self) -> RailState:
        """Position, velocity, following error and status in one round trip."""
        lines = self.port.command(self._poll)
        want = 4 if self.watchdog is None else 5
        if len(lines) != want:
            raise PmacProtocolError(f"{self._poll!r}: expected {want} lines, got {lines!r}")
        try:
            p, v, f = (float(x) for x in lines[:3])
        except ValueError:
            raise PmacProtocolError(f"{self._poll!r}: bad numbers in {lines!r}") from None
        c = self.config
        return RailState(position=c.to_metres(p),
                         velocity=c.to_metres(v) / self.servo_period,
                         following_error=c.to_metres(f),
                         status=MotorStatus.from_hex(lines[3]),
                         armed=None if self.watchdog is None else
                         parse_number(lines[4:5], "armed flag") != 0.0)

    def status(self) -> MotorStatus:
        lines = self.port.command(f"#{self.motor}?")
        if len(lines) != 1:
            raise PmacProtocolError(f"#{self.motor}?: expected one line, got {lines!r}")
        return MotorStatus.from_hex(lines[0])

    # -- motion ---------------------------------------------------------------------------
    def jog_to(self, metres: float) -> tuple[float, MotorStatus]:
        """Jog to an absolute position (m) at the jog speed; returns (target in counts, the
        motor status read on the card just before the jog, in the same command line). With
        the safety PLC the line also reads its armed flag first: :attr:`last_jog_armed`.

        A jog closes the loop of a killed motor, so the caller must check that status: if it
        shows the motor killed, the jog re-enabled it and the caller must kill it again.
        Raises RailCommandError (nothing sent) if not finite or outside the soft limits.
        """
        c = self.config
        x = c.check_position(metres)
        lo, hi = sorted((c.to_counts(c.lower), c.to_counts(c.upper)))
        # One decimal is plenty (0.1 count); round toward the inside at the very limits so
        # that formatting can never push the target past them.
        counts = min(max(math.floor(c.to_counts(x) * 10 + 0.5) / 10, math.ceil(lo * 10) / 10),
                     math.floor(hi * 10) / 10)
        line = f"#{self.motor}?#{self.motor}J={counts:.1f}"
        if self.watchdog is None:
            lines = self.port.command(line)
            if len(lines) != 1:
                raise PmacProtocolError(f"jog: expected the status line, got {lines!r}")
            return counts, MotorStatus.from_hex(lines[0])
        # streamed setpoints feed the watchdog too; the armed flag read in the same line
        # tells the caller at once if the safety PLC had tripped (the jog then ran unarmed)
        hb = f"P{self.watchdog.heartbeat}"
        lines = self.port.command(f"{hb}={hb}+1 P{self.watchdog.armed} {line}")
        if len(lines) != 2:
            raise PmacProtocolError(f"jog: expected the armed flag and the status line, "
                                    f"got {lines!r}")
        self.last_jog_armed = parse_number(lines[:1], "armed flag") != 0.0
        return counts, MotorStatus.from_hex(lines[1])

    def stop(self) -> None:
        """``#nJ/``: decelerate and hold position with the servo on (also closes the loop)."""
        self.port.command(f"#{self.motor}J/")

    def stop_checked(self) -> MotorStatus:
        """``#n?#nJ/``: like :meth:`stop`, returning the motor status read on the card just
        before it, in the same command line. ``J/`` closes the loop of a killed motor, so
        the caller must check that status (as for :meth:`jog_to`)."""
        return self._status_then(f"#{self.motor}J/")

    def home_checked(self) -> MotorStatus:
        """``#n?#nHM``: like :meth:`home`, with the status read just before it (``HM`` also
        closes the loop of a killed motor)."""
        return self._status_then(f"#{self.motor}HM")

    def _status_then(self, command: str) -> MotorStatus:
        lines = self.port.command(f"#{self.motor}?{command}")
        if len(lines) != 1:
            raise PmacProtocolError(f"{command}: expected the status line, got {lines!r}")
        return MotorStatus.from_hex(lines[0])

    def enable(self) -> None:
        """Close the loop and hold at the present position (``#nJ/``); with the safety PLC
        also re-activate the motor (Ixx00=1) and arm the watchdog."""
        m = self.motor
        if self.watchdog is None:
            self.port.command(f"#{m}J/")
        else:
            # the heartbeat in the same line: the PLC re-arms its timer in the very scan in
            # which it first sees the armed flag, so arming never trips on an old timer
            hb = f"P{self.watchdog.heartbeat}"
            self.port.command(f"{hb}={hb}+1 I{m * 100}=1 P{self.watchdog.armed}=1 #{m}J/")

    def kill(self) -> None:
        """``#nK``: open the loop and disable the amplifier (and disarm the watchdog)."""
        m = self.motor
        if self.watchdog is None:
            self.port.command(f"#{m}K")
        else:
            self.port.command(f"P{self.watchdog.armed}=0 #{m}K")

    def home(self) -> None:
        """``#nHM``: start the home search (Ixx23 speed/direction, Ixx26 offset)."""
        self.port.command(f"#{self.motor}HM")

