"""The rail driver core (no ROS): a worker thread that owns the PMAC link.

The worker polls the axis at ``rate`` (one round trip: heartbeat, position, velocity,
following error, status, the safety PLC's armed flag), sends the newest setpoint, runs
one-shot requests (home, hold, enable, kill) and supervises the link: a timeout or a closed
socket marks the link down at once (so loss is seen within ``timeout + 1/rate``), drops any
pending setpoint (nothing stale is sent later), fails waiting requests, and reconnects every
``reconnect_period``, logging why it cannot connect (throttled per reason).

Torque rule (one for every driver, docs/architecture.md): torque is on only after a
successful ``enable`` (``set_torque true``) on the present connection. On every (re)connect
the driver kills a motor that is enabled; setpoints, hold and home are refused until
``enable``. A motor the card killed (fatal following error, amplifier fault), one killed by
the safety PLC's watchdog, or one found killed while the driver had torque on is *latched*:
the driver stops sending anything that moves it, kills it again if a jog raced with the kill
(every jog closes a killed motor's loop on the card, see watchdog.py), reports the fault in
:attr:`DriverSnapshot.latched` (and so on ``/diagnostics``) until ``enable`` succeeds, and
logs it once. Callers (the ROS node) read :meth:`RailDriver.snapshot` and call
:meth:`set_target` / :meth:`request` from any thread.
"""
from __future__ import annotations

import math
import re
import threading
import time
import traceback
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, replace
from typing import Callable, NoReturn, Sequence

from ..log_throttle import ReasonThrottle
from .axis import MotorStatus, RailAxis, RailState
from .errors import PmacCommandError, PmacError, PmacLinkError, PmacProtocolError, \
    RailCommandError, RailError

__all__ = ["RailDriver", "DriverSnapshot", "REQUESTS", "OK", "WARN", "ERROR", "check_command",
           "reason_key"]

OK, WARN, ERROR = 0, 1, 2          # diagnostic levels (diagnostic_msgs/DiagnosticStatus)
REQUESTS = ("home", "hold", "enable", "kill")
WATCHDOG_TRIP = "watchdog PLC tripped"   # the start of a watchdog trip's latched reason
Logger = Callable[[str, str], None]   # (level: "info" | "warn" | "error", message)


def reason_key(message: str) -> str:
    """A throttling key: the message with its numbers taken out (a value or address that
    changes does not make a new reason, a different kind of problem does)."""
    return re.sub(r"[-+]?\d[\d.]*(e[-+]?\d+)?", "#", message)


def check_command(names: Sequence[str], positions: Sequence[float],
                  efforts: Sequence[float], joint: str) -> str | None:
    """Why a ``joint_command`` that names ``joint`` is rejected whole, or None.

    The contract (docs/architecture.md): a malformed message (length mismatch, NaN/inf in
    any joint's value, duplicate names) is rejected whole, so that no driver applies part of
    it while another refuses it; the rail is position-controlled: an effort for it other
    than 0 (0 or an empty effort array = no extra limit) is refused.
    """
    if names.count(joint) > 1:
        return f"{joint!r} named twice in one joint_command"
    if len(positions) != len(names):
        return f"{len(positions)} positions for {len(names)} names"
    if len(efforts) not in (0, len(names)):
        return f"{len(efforts)} efforts for {len(names)} names"
    for kind, values in (("position", positions), ("effort", efforts)):
        for name, v in zip(names, values):
            if not math.isfinite(v):
                return f"{kind} of {name!r} is not finite ({v}): the whole message is rejected"
    if efforts and efforts[names.index(joint)] != 0.0:
        return (f"effort {efforts[names.index(joint)]:g} for {joint!r} refused: the rail is "
                "position-controlled (send 0 or no effort)")
    return None


@dataclass(frozen=True)
class DriverSnapshot:
    """What the driver knows now. ``state`` is the last poll (None before the first);
    ``latched``: faults seen since the last successful enable (cleared only by it)."""

    link_up: bool
    state: RailState | None
    stamp: float                 # time.monotonic() of ``state``
    round_trip: float            # s, last poll
    reconnects: int
    rejected_setpoints: int
    last_error: str
    endpoint: str
    motor: int
    torque: bool = False         # the driver has torque on (enabled on this connection)
    latched: tuple[str, ...] = ()
    watchdog: bool = False       # the safety PLC is downloaded and fed
    watchdog_trips: int = 0      # times the safety PLC stopped the rail (heartbeat lost)
    last_rejection: str = ""     # why the last setpoint was refused ("" = none yet)

    @property
    def homed(self) -> bool:
        return bool(self.state and self.state.status.home_complete)

    def diagnostic(self) -> tuple[int, str, list[tuple[str, str]]]:
        """(level, message, key/values) for ``/diagnostics``."""
        s = self.state
        kv = [("link", "up" if self.link_up else "down"), ("endpoint", self.endpoint),
              ("motor", str(self.motor)), ("torque", "on" if self.torque else "off"),
              ("latched_faults", ", ".join(self.latched) or "none"),
              ("watchdog", "on" if self.watchdog else "off"),
              ("watchdog_trips", str(self.watchdog_trips))]
        if s is not None:
            st = s.status
            kv += [("position_m", f"{s.position:.6f}"), ("velocity_mps", f"{s.velocity:.6f}"),
                   ("following_error_m", f"{s.following_error:.6f}")]
            kv += [(k, str(getattr(st, a)).lower()) for k, a in (
                ("homed", "home_complete"), ("amp_enabled", "amp_enabled"),
                ("in_position", "in_position"), ("neg_limit", "neg_limit"),
                ("pos_limit", "pos_limit"), ("amp_fault", "amp_fault"),
                ("fatal_following_error", "fatal_following_error"),
                ("warning_following_error", "warning_following_error"))]
            kv.append(("status_word", st.hex()))
        kv += [("round_trip_ms", f"{self.round_trip * 1e3:.3f}"),
               ("reconnects", str(self.reconnects)),
               ("rejected_setpoints", str(self.rejected_setpoints)),
               ("last_rejection", self.last_rejection or "none"),
               ("last_error", self.last_error)]
        if not self.link_up:
            return ERROR, f"PMAC link down: {self.last_error}", kv
        if self.latched:
            return ERROR, (f"latched: {'; '.join(self.latched)} "
                           "(motor killed; set_torque true clears)"), kv
        if s is None:
            return WARN, "connected, no status yet", kv
        st = s.status
        problems = []
        if st.neg_limit or st.pos_limit:
            problems.append("on " + " and ".join(
                n for n, on in (("negative", st.neg_limit), ("positive", st.pos_limit)) if on)
                + " limit switch")
        if st.warning_following_error:
            problems.append("following error warning")
        if not st.amp_enabled:
            problems.append("torque off (killed)")
        if st.home_search:
            problems.append("homing")
        elif not st.home_complete:
            problems.append("not homed")
        if problems:
            return WARN, ", ".join(problems), kv
        return OK, "ok", kv


_FAULT_TEXT = {"amp_fault": "amplifier fault", "fatal_following_error": "fatal following error",
               "i2t_fault": "I2T amplifier fault",
               "integrated_following_error": "integrated following error"}


def _fault_reason(st: MotorStatus) -> str:
    return ", ".join(_FAULT_TEXT.get(f, f) for f in st.faults)


class _Request:
    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.future: Future[str] = Future()


class RailDriver:
    """Owns ``axis.port`` (a PMAC client) in one worker thread; see the module docstring.

    ``rate`` Hz (polls), ``reconnect_period`` s; ``require_homing``: refuse setpoints before
    home complete; ``configure_card``: set I3/I6, write Ixx22/19/20/21/13/14 and download the
    safety PLC on each connect (else I3/I6 are only checked); ``log_period`` s: the same
    connection problem is logged at most this often.
    """

    def __init__(self, axis: RailAxis, rate: float = 50.0, reconnect_period: float = 1.0,
                 require_homing: bool = True, configure_card: bool = True,
                 log: Logger | None = None, log_period: float = 10.0) -> None:
        if not 1.0 <= rate <= 1000.0:
            raise ValueError(f"rate must be within 1..1000 Hz, got {rate}")
        if not 0.01 <= reconnect_period <= 600.0:
            raise ValueError(f"reconnect_period must be within 0.01..600 s, got {reconnect_period}")
        for attr in ("connect", "close", "connected"):
            if not hasattr(axis.port, attr):
                raise TypeError(f"axis.port must be a PMAC client (no {attr!r})")
        if axis.watchdog is not None and not configure_card:
            raise ValueError("the watchdog PLC is downloaded when the driver configures the "
                             "card: it needs configure_card")
        if axis.watchdog is not None and axis.watchdog.timeout < 2.0 / rate:
            raise ValueError(f"watchdog timeout {axis.watchdog.timeout:g} s must be at least "
                             f"two poll periods ({2.0 / rate:g} s at {rate:g} Hz)")
        self.axis = axis
        self.client = axis.port
        self.period = 1.0 / rate
        self.reconnect_period = float(reconnect_period)
        self.require_homing = bool(require_homing)
        self.configure_card = bool(configure_card)
        self._logger = log
        self._throttle = ReasonThrottle(log_period)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._requests: list[_Request] = []
        self._target: float | None = None       # m, pending (newest wins)
        self._sent_counts: float | None = None  # last J= target, counts
        self._snap = DriverSnapshot(False, None, 0.0, float("nan"), 0, 0, "not connected yet",
                                    getattr(self.client, "endpoint", "?"), axis.motor)
        self._ever_connected = False

    def _log(self, level: str, message: str) -> None:
        if self._logger is None:
            return
        try:
            self._logger(level, message)
        except Exception:  # noqa: BLE001 - a logging problem must not stop the worker
            traceback.print_exc()

    def _log_throttled(self, level: str, reason: str, message: str) -> None:
        if self._throttle.allow(reason_key(reason)):
            self._log(level, message)

    # -- life cycle -----------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("driver already started")
        self._thread = threading.Thread(target=self._run, name="pmac-rail-driver", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the worker, halt a motion in progress and close the link.

        A motor that is enabled and moving gets ``#nJ/`` (decelerate, hold with the servo
        on): a controller that goes away must not leave the carriage travelling to its last
        target. A killed motor is left killed (``J/`` would close its loop).
        """
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
        worker_gone = self._thread is None or not self._thread.is_alive()
        if worker_gone and self.client.connected and self.snapshot().link_up:
            try:
                st = self.axis.status()
                if st.amp_enabled and not st.desired_velocity_zero:
                    self.axis.stop()
                    self._log("info", "rail was moving at shutdown: stopped (J/)")
            except PmacError as exc:
                self._log("warn", f"could not stop the rail at shutdown: {exc}")
        self.client.close()
        with self._lock:
            reqs, self._requests = self._requests, []
        for r in reqs:
            r.future.set_exception(RailCommandError("driver stopped"))

    # -- API for any thread ---------------------------------------------------------------
    def snapshot(self) -> DriverSnapshot:
        with self._lock:
            return self._snap

    def set_target(self, metres: float) -> float:
        """Queue a rail setpoint (m); returns it. Raises RailCommandError if refused:
        not finite, outside the soft limits, link down, torque off, fault latched, homing or
        not homed (when required). Nothing is sent for a refused setpoint."""
        try:
            x = self.axis.config.check_position(metres)
            snap = self.snapshot()
            if not snap.link_up or snap.state is None:
                raise RailCommandError(f"PMAC link down ({snap.last_error})")
            if snap.latched:
                raise RailCommandError(f"fault latched: {'; '.join(snap.latched)}; "
                                       "call rail/set_torque true to clear it")
            if not snap.torque:
                raise RailCommandError("torque is off; call rail/set_torque true")
            st = snap.state.status
            if st.home_search:
                raise RailCommandError("homing in progress")
            if self.require_homing and not st.home_complete:
                raise RailCommandError("rail not homed; call rail/home first")
        except RailCommandError as exc:
            self.reject(str(exc))
        with self._lock:
            self._target = x
        self._wake.set()
        return x

    def reject(self, reason: str) -> NoReturn:
        """Count a refused setpoint (shown in diagnostics) and raise RailCommandError."""
        with self._lock:
            self._snap = replace(self._snap, rejected_setpoints=self._snap.rejected_setpoints + 1,
                                 last_rejection=reason)
        raise RailCommandError(reason)

    def request(self, kind: str, timeout: float = 2.0) -> str:
        """Run ``home`` / ``hold`` / ``enable`` / ``kill`` on the worker; wait for it.

        Returns a human-readable result; raises RailCommandError (refused or failed, with the
        reason) or PmacError from the card.
        """
        if kind not in REQUESTS:
            raise ValueError(f"unknown request {kind!r}; known: {REQUESTS}")
        if not self.snapshot().link_up:
            raise RailCommandError(f"PMAC link down ({self.snapshot().last_error})")
        req = _Request(kind)
        with self._lock:
            self._requests.append(req)
        self._wake.set()
        try:
            return req.future.result(timeout)
        except FutureTimeout:
            raise RailCommandError(f"{kind}: no result within {timeout:g} s") from None

    # -- worker ---------------------------------------------------------------------------
    def _run(self) -> None:
        next_poll = time.monotonic()
        while not self._stop.is_set():
            if not self.client.connected or not self.snapshot().link_up:
                if not self._connect():
                    self._stop.wait(self.reconnect_period)
                    continue
                next_poll = time.monotonic()
            try:
                self._serve_requests()
                self._send_target()
                if time.monotonic() >= next_poll:
                    self._poll()
                    next_poll += self.period
                    if next_poll < time.monotonic():      # fell behind: don't burst
                        next_poll = time.monotonic() + self.period
                self._report_messages()
            except (PmacLinkError, PmacProtocolError) as exc:
                self._link_lost(exc)
                continue
            except (PmacCommandError, RailError) as exc:
                self._note_error(str(exc), "error")
            except Exception as exc:  # noqa: BLE001 - a bug: report it, resync, keep running
                self._log("error", f"internal error in the rail driver: {exc!r}\n"
                                   f"{traceback.format_exc()}")
                self._link_lost(exc)
                continue
            self._wake.wait(max(0.0, next_poll - time.monotonic()))
            self._wake.clear()

    def _connect(self) -> bool:
        try:
            self.client.connect()
            if self.configure_card:
                self.axis.configure()
            else:
                self.axis.check_communication()
                self.axis.read_servo_period()
            state = self.axis.read()
            killed = state.status.amp_enabled
            if killed:          # the torque rule: on only after enable on this connection
                self.axis.kill()
                state = self.axis.read()
        except PmacError as exc:
            self.client.close()
            with self._lock:
                self._snap = replace(self._snap, link_up=False, last_error=str(exc),
                                     torque=False)
            self._log_throttled("error", f"connect:{type(exc).__name__}:{exc}",
                                f"cannot use the PMAC at {self._snap.endpoint}: {exc}; "
                                f"retrying every {self.reconnect_period:g} s")
            return False
        with self._lock:
            reconnects = self._snap.reconnects + (1 if self._ever_connected else 0)
            self._snap = replace(self._snap, link_up=True, state=state, stamp=time.monotonic(),
                                 reconnects=reconnects, last_error="", torque=False,
                                 watchdog=self.configure_card and self.axis.watchdog is not None)
            self._target, self._sent_counts = None, None
        word = "reconnected to" if self._ever_connected else "connected to"
        self._ever_connected = True
        self._log("info", f"{word} PMAC at {self._snap.endpoint}, motor {self.axis.motor}: "
                          f"{state.position:.4f} m, homed={state.status.home_complete}, "
                          f"torque off{' (it was on: killed)' if killed else ''}, watchdog "
                          f"{'on' if self._snap.watchdog else 'off'}; "
                          "set_torque true to move")
        return True

    def _link_lost(self, exc: Exception) -> None:
        self.client.close()
        with self._lock:
            had_torque = self._snap.torque
            latched = self._snap.latched + (
                ("link lost while torque was on",) if had_torque else ())
            self._snap = replace(self._snap, link_up=False, last_error=str(exc), torque=False,
                                 latched=_unique(latched))
            self._target, self._sent_counts = None, None
            reqs, self._requests = self._requests, []
        for r in reqs:
            r.future.set_exception(RailCommandError(f"PMAC link lost: {exc}"))
        self._log("error", f"PMAC link lost ({exc}); setpoints dropped, "
                           f"{'the watchdog PLC stops the rail, ' if self._snap.watchdog else ''}"
                           f"reconnecting every {self.reconnect_period:g} s")

    def _note_error(self, msg: str, level: str) -> None:
        with self._lock:
            self._snap = replace(self._snap, last_error=msg)
        self._log_throttled(level, f"error:{msg}", msg)

    def _report_messages(self) -> None:
        msgs = getattr(self.client, "messages", None)
        while msgs:
            text = msgs.popleft()
            self._log_throttled("info", f"message:{text}", f"message from the card: {text!r}")

    def _latch(self, reason: str, detail: str = "") -> None:
        """Latch a fault: disarm, kill (again), report once; the worker thread only."""
        with self._lock:
            new = reason not in self._snap.latched
            self._snap = replace(self._snap, torque=False,
                                 latched=_unique(self._snap.latched + (reason,)),
                                 watchdog_trips=self._snap.watchdog_trips + (
                                     reason.startswith(WATCHDOG_TRIP)))
            self._target, self._sent_counts = None, None
        self.axis.kill()
        if new:
            self._log("error", f"rail fault latched: {reason}{detail}; motor killed, "
                               "setpoints refused until set_torque true")

    def _poll(self) -> None:
        t0 = time.perf_counter()
        state = self.axis.read()
        rt = time.perf_counter() - t0
        with self._lock:
            prev = self._snap.state
            torque = self._snap.torque
            self._snap = replace(self._snap, state=state, stamp=time.monotonic(), round_trip=rt)
        st = state.status
        if st.faults:
            self._latch(f"{_fault_reason(st)} on the card")
        elif torque and not st.amp_enabled:     # (the safety PLC disarms on any kill too)
            self._latch("motor killed (by the card or another host)")
        elif torque and state.armed is False:
            self._latch(f"{WATCHDOG_TRIP} (heartbeat lost): the card stopped the rail")
        elif not torque and st.amp_enabled:
            self._latch("motor enabled by someone else while the driver had torque off")
        if prev is not None:
            self._report_transitions(prev.status, st)

    def _report_transitions(self, a: MotorStatus, b: MotorStatus) -> None:
        for name, level, text in (
                ("neg_limit", "warn", "negative limit switch active"),
                ("pos_limit", "warn", "positive limit switch active"),
                ("home_complete", "info", "home complete")):
            if getattr(b, name) and not getattr(a, name):
                self._log(level, text)
        if a.home_search and not b.home_search and not b.home_complete:
            self._log("error", "home search ended without home complete (limit switch?)")

    def _send_target(self) -> None:
        with self._lock:
            target, self._target = self._target, None
            torque = self._snap.torque
        if target is None or not torque:
            return
        counts = self.axis.config.to_counts(target)
        if self._sent_counts is not None and abs(counts - self._sent_counts) < 0.05:
            return
        self._sent_counts, before = self.axis.jog_to(target)
        if before.faults or not before.amp_enabled:
            # the card had killed the motor since the last poll: the jog just closed its loop
            self._latch(f"{_fault_reason(before)} on the card" if before.faults else
                        "motor killed by the card", " (seen with a setpoint: killed again)")
        elif self.axis.last_jog_armed is False:
            # the safety PLC tripped since the last poll (this worker was late: the very
            # condition of a trip, so the next poll may be late too): the jog ran unarmed
            self._latch(f"{WATCHDOG_TRIP} (heartbeat lost): the card stopped the rail",
                        " (seen with a setpoint: killed)")

    def _serve_requests(self) -> None:
        with self._lock:
            reqs, self._requests = self._requests, []
        for r in reqs:
            if r.future.set_running_or_notify_cancel():
                try:
                    result = self._do(r.kind)
                    self._poll()          # the caller sees the state after the request
                    if r.kind == "enable" and self.snapshot().latched:
                        raise RailCommandError(
                            f"enabled, but {'; '.join(self.snapshot().latched)}")
                    r.future.set_result(result)
                except (PmacLinkError, PmacProtocolError) as exc:
                    r.future.set_exception(RailCommandError(f"PMAC link lost: {exc}"))
                    raise
                except PmacError as exc:
                    r.future.set_exception(exc)

    def _do(self, kind: str) -> str:
        ax = self.axis
        with self._lock:
            self._target, self._sent_counts = None, None
        if kind == "kill":
            ax.kill()
            with self._lock:
                self._snap = replace(self._snap, torque=False)
            return "motor killed (torque off)"
        if kind == "enable":
            ax.enable()
            st = ax.status()
            if not st.amp_enabled or st.faults:
                ax.kill()
                raise RailCommandError("the card did not enable the motor"
                                       + (f": {_fault_reason(st)}" if st.faults else ""))
            with self._lock:
                cleared = self._snap.latched
                self._snap = replace(self._snap, torque=True, latched=())
            if cleared:
                self._log("info", f"torque on; cleared latched: {'; '.join(cleared)}")
            return "torque on, holding position" + (
                f" (cleared: {'; '.join(cleared)})" if cleared else "")
        snap = self.snapshot()
        if snap.latched:
            raise RailCommandError(f"fault latched: {'; '.join(snap.latched)}; "
                                   "call rail/set_torque true first")
        if not snap.torque:
            raise RailCommandError("torque is off; call rail/set_torque true first")
        # J/ and HM close the loop of a motor the card killed since the last poll (the
        # latch above can be one poll old). So: read the status first and refuse if the
        # motor is killed; then send the command with the status read again in the same
        # line, and if a kill landed in between (one round trip), kill it again at once.
        # Either way the fault is latched and the request refused.
        for check in (ax.status, ax.stop_checked if kind == "hold" else ax.home_checked):
            st = check()
            if st.faults or not st.amp_enabled:
                reason = (f"{_fault_reason(st)} on the card" if st.faults else
                          "motor killed by the card")
                self._latch(reason, f" (seen with rail/{kind})")
                raise RailCommandError(f"{kind} refused: {reason}; call rail/set_torque "
                                       "true first")
        return "holding" if kind == "hold" else "home search started"


def _unique(items: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(items))
