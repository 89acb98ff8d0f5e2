"""The driver core: commands, safety, watchdog, cycle and reconnection (no ROS).

:class:`DynamixelDriver` owns a :class:`DynamixelBus`. ``cycle(now)`` does one sync read +
one sync write; while the port is down it retries opening it every ``reconnect_period``.
Commands arrive by joint name (``command``); positions are clamped into the joint limits,
NaN/inf rejected (in any joint of the message, also one another driver owns); efforts clamped
to the servo's current limit. Every position-class command (position only, position +
effort) runs in current-based position (mode 5), so switching between them never switches
the operating mode; effort only runs in current mode (0). The current limit of a position
command is its effort, or the joint's default limit when the effort is 0 or absent.

A joint in current (torque) control whose effort command is older than ``command_timeout``
is switched to hold its present position (watchdog). The servo does not enforce position
limits in current mode, so the driver brakes before a limit: inside a margin that grows with
the velocity toward the limit (``limit_margin`` + v·horizon + v²/(2·``brake_decel``)) a
moving joint gets the full torque against its motion (the horizon is ``brake_cycles`` times
the worst recent cycle gap), a slow one no torque toward the limit;
over ``limit_ramp`` before that margin a torque toward the limit fades out linearly.
The servo side of the watchdog: a joint in current mode has its Bus Watchdog armed (at most
``command_timeout``, 0.1 s by default), so it stops by itself if the driver's cycle stops
(host stalled, port lost, driver dead);
a trip seen after a stall is logged and the joint held. The torque state reported is the one
read from each servo every cycle (a servo turns its torque off by itself on overload or
overheating).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .bus import BusState, DynamixelBus
from .config import BusConfig
from .control_table import OperatingMode, decode_hardware_error
from .errors import CommandError, CommError, PortError, PortLostError, StartupError

__all__ = ["CommandReport", "DynamixelDriver", "Status", "OK", "WARN", "ERROR", "STALE"]

OK, WARN, ERROR, STALE = 0, 1, 2, 3   # diagnostic levels (diagnostic_msgs/DiagnosticStatus)

_log = logging.getLogger(__name__)

CBP = "current_based_position"    # every position-class command
CURRENT = "current"               # effort-only commands
BRAKE_MIN_SPEED = 0.05            # rad/s: slower joints are not braked, only not pushed


@dataclass
class CommandReport:
    """What became of a command: joints clamped into limits (positions) or current limits."""

    clamped: list[str] = field(default_factory=list)
    effort_clamped: list[str] = field(default_factory=list)
    torque_off: list[str] = field(default_factory=list)   # accepted, but their torque is off
    port_down: bool = False       # accepted while the port is down: nothing can move


@dataclass(frozen=True)
class Status:
    """One diagnostic status: the content of a diagnostic_msgs/DiagnosticStatus."""

    name: str
    hardware_id: str
    level: int
    message: str
    values: tuple[tuple[str, str], ...]


class DynamixelDriver:
    """Bus + per-joint goals + safety. Arrays are in ``config.joints`` order."""

    def __init__(self, bus: DynamixelBus, *, command_timeout: float = 0.5,
                 reconnect_period: float = 0.5, other_joints: Sequence[str] = (),
                 brake_decel: float = 10.0, limit_margin: float = 0.005,
                 limit_ramp: float = 0.3, brake_cycles: float = 2.0,
                 bus_watchdog: float | None = None) -> None:
        """``other_joints``: names of joints driven by other drivers (e.g. ``rail``), ignored
        in commands; any other name not on this bus makes a command invalid.

        Torque mode near a limit: ``brake_decel`` (rad/s²) is the deceleration assumed when
        braking, ``limit_margin`` (rad) the margin kept at rest, ``limit_ramp`` (rad) the
        distance before the margin over which a torque toward the limit fades out,
        ``brake_cycles`` the number of (measured) cycle periods the joint may travel before
        the brake acts. ``bus_watchdog`` (s, default min(command_timeout, 0.1)): the servos'
        Bus Watchdog in current mode, fed by this driver's own cycle: if the cycle stops
        (host stalled, port lost, driver dead) a servo in current mode stops by itself, also
        before a limit the host can no longer brake for.
        """
        if not 0.0 < command_timeout <= 60.0:
            raise ValueError(f"command_timeout must be in (0, 60] s, got {command_timeout}")
        if not 0.0 < reconnect_period <= 60.0:
            raise ValueError(f"reconnect_period must be in (0, 60] s, got {reconnect_period}")
        if not 0.0 < brake_decel < math.inf:
            raise ValueError(f"brake_decel must be > 0 rad/s², got {brake_decel}")
        if not 0.0 <= limit_margin < 1.0:
            raise ValueError(f"limit_margin must be in [0, 1) rad, got {limit_margin}")
        if not 0.0 < limit_ramp < 1.0:
            raise ValueError(f"limit_ramp must be in (0, 1) rad, got {limit_ramp}")
        if not 0.0 <= brake_cycles <= 100.0:
            raise ValueError(f"brake_cycles must be in [0, 100], got {brake_cycles}")
        self.brake_decel = brake_decel
        self.limit_margin = limit_margin
        self.limit_ramp = limit_ramp
        self.brake_cycles = brake_cycles
        self._last_apply = -math.inf
        self._gap = 0.01                 # s, worst recent cycle gap (brake horizon)
        self._last_goals: tuple[np.ndarray, np.ndarray] | None = None   # ticks, raw current
        self.bus = bus
        bus.set_bus_watchdog(min(command_timeout, 0.1) if bus_watchdog is None else bus_watchdog)
        self.config: BusConfig = bus.config
        self.other_joints = frozenset(other_joints) - set(bus.config.names)
        self.command_timeout = command_timeout
        self.reconnect_period = reconnect_period
        n = len(self.config.joints)
        self.lower = np.array([j.lower for j in self.config.joints])
        self.upper = np.array([j.upper for j in self.config.joints])
        self.max_effort = np.array([j.effort_limit for j in self.config.joints])
        self._hold_effort = np.array([j.hold_effort if j.hold_effort is not None
                                      else j.effort_limit for j in self.config.joints])
        self.goal_position = np.zeros(n)        # rad
        self.goal_effort = self._hold_effort.copy()  # N·m (limit in cbp, torque in current)
        self.control = [CBP] * n          # wanted control mode (CBP or CURRENT)
        self.effort_stamp = np.full(n, -math.inf)
        self.state: BusState | None = None
        self.connected = False
        self.missing: list[str] = []
        self.last_error = ""
        self.reconnects = 0
        self.last_ok = -math.inf
        self._next_attempt = 0.0
        self._have_goal = False
        self.watchdog_trips = 0
        self.cycles = 0                  # successful cycles since start
        self._window = (0, 0)            # bus transactions, failures at the last diagnostics
        self.brakes = 0                  # cycles in which a joint was braked before a limit
        # (logging level, text) of events for the node to log
        self.events: list[tuple[int, str]] = []

    # -- helpers -----------------------------------------------------------------------------
    def _event(self, text: str, level: int = logging.INFO) -> None:
        self.events.append((level, text))
        _log.debug(text)     # the node logs the events (pop_events) at their level

    def pop_events(self) -> list[tuple[int, str]]:
        """Events since the last call: (logging level, text)."""
        out, self.events = self.events, []
        return out

    @property
    def names(self) -> list[str]:
        return self.config.names

    # -- connection --------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port and run the start-up check (torque stays off). Raises PortError or
        StartupError."""
        try:
            self.bus.open()
            self.bus.startup()
        except (PortError, StartupError, CommError) as exc:
            self.bus.close()
            self.connected = False
            self.last_error = str(exc)
            if isinstance(exc, StartupError):
                self.missing = exc.missing
            raise
        self.connected = True
        self.last_ok = time.monotonic()
        self.missing = []
        self.state = self.bus.read_state()
        self._reset_goals_to_present()
        if self.bus.want_fast and not self.bus.fast:
            self._event(f"{self.bus.fast_error}; using plain Sync Read (0x82)", logging.WARNING)

    def _reset_goals_to_present(self) -> None:
        assert self.state is not None
        self.goal_position = np.clip(self.state.position, self.lower, self.upper)
        self.goal_effort = self._hold_effort.copy()
        self.control = [CBP] * len(self.control)
        self.effort_stamp[:] = -math.inf
        self._have_goal = True

    def _lost(self, exc: Exception, now: float) -> None:
        self.connected = False
        self._last_goals = None
        self.state = None
        self.last_error = str(exc)
        self.bus.close()
        self._next_attempt = now + self.reconnect_period
        self._event(f"port lost: {exc}; torque will be off after reconnecting",
                    logging.WARNING)

    # -- commands ----------------------------------------------------------------------------
    def command(self, names: Sequence[str], position: Sequence[float] = (),
                effort: Sequence[float] = (), now: float | None = None) -> CommandReport:
        """Apply a by-name command (names in ``other_joints`` are ignored).

        position only -> current-based position with the joint's default current limit;
        position and effort -> current-based position with |effort| (N·m) as the limit, an
        effort of 0 meaning the default limit; effort only -> current control (torque, N·m).
        Raises CommandError (nothing applied) on length mismatch, duplicates, an unknown joint
        name or NaN/inf in any joint, one of ``other_joints`` included. A command for other
        drivers' joints only changes nothing.
        """
        now = time.monotonic() if now is None else now
        n = len(names)
        try:
            position = [float(x) for x in position]
            effort = [float(x) for x in effort]
        except (TypeError, ValueError) as exc:
            raise CommandError(f"setpoints must be numbers: {exc}", "type") from None
        if len(position) not in (0, n) or len(effort) not in (0, n):
            raise CommandError(f"{len(position)} positions and {len(effort)} efforts for "
                               f"{n} joint names (each must be 0 or {n})", "length")
        if not position and not effort:
            raise CommandError("command has neither positions nor efforts", "empty")
        if len(set(names)) != n:
            raise CommandError(f"duplicate joint names in command: {list(names)}", "duplicate")
        idx: list[tuple[int, int]] = []
        unknown = []
        for k, name in enumerate(names):
            try:
                idx.append((k, self.config.index(name)))
            except KeyError:
                if name not in self.other_joints:
                    unknown.append(name)
        if unknown:
            raise CommandError(f"unknown joint(s) {unknown}; known: "
                               f"{self.names + sorted(self.other_joints)}", "unknown_joint")
        bad = [names[k] for k in range(n)
               if (position and not math.isfinite(position[k]))
               or (effort and not math.isfinite(effort[k]))]
        if bad:
            raise CommandError(f"non-finite setpoint for {bad}: command rejected whole",
                               "non_finite")
        report = CommandReport(port_down=bool(idx) and not self.connected)
        for k, i in idx:
            name = self.config.joints[i].name
            e = 0.0
            if effort:
                e = float(effort[k])
                lim = self.max_effort[i]
                if abs(e) > lim:
                    report.effort_clamped.append(name)
                    e = math.copysign(lim, e)
            if position:
                q = float(position[k])
                qc = min(max(q, self.lower[i]), self.upper[i])
                if qc != q:
                    report.clamped.append(name)
                self.goal_position[i] = qc
                self.control[i] = CBP
                # effort 0 or absent: no extra limit, the joint's default limit applies
                self.goal_effort[i] = abs(e) if e != 0.0 else self._hold_effort[i]
            else:
                self.control[i] = CURRENT
                self.goal_effort[i] = e
                self.effort_stamp[i] = now
            if self.connected and not self.bus.torque[i]:
                report.torque_off.append(name)
        self._have_goal = True
        return report

    def hold(self) -> None:
        """Every arm joint: hold the present position (current-based position, default
        limit). The gripper, when it is position-controlled (closing or squeezing at its
        current limit), keeps its goal and limit: holding it where it is would end the
        squeeze and drop a held object. An effort-controlled gripper is held like a joint."""
        if self.state is None:
            raise PortLostError("no state: port down")
        keep = [i for i, j in enumerate(self.config.joints)
                if j.gripper and self.control[i] == CBP and self._have_goal]
        kept = [(self.goal_position[i], self.goal_effort[i]) for i in keep]
        self._reset_goals_to_present()
        for i, (goal, effort) in zip(keep, kept):
            self.goal_position[i], self.goal_effort[i] = goal, effort

    # -- cycle -------------------------------------------------------------------------------
    def cycle(self, now: float | None = None) -> BusState | None:
        """One control cycle. Returns the state read, or None while the port is down."""
        now = time.monotonic() if now is None else now
        if not self.connected:
            if now < self._next_attempt:
                return None
            self._next_attempt = now + self.reconnect_period
            try:
                self.connect()
            except (PortError, StartupError, CommError) as exc:
                self.last_error = str(exc)
                return None
            self.reconnects += 1
            self._event(f"connected to {self.bus.port_name} ({len(self.names)} servos); "
                        "torque off")
        t0 = time.perf_counter()
        try:
            before = list(self.bus.torque)
            self.state = self.bus.read_state()
            self._torque_dropped(before)
            self.last_ok = now
            self._apply(now)
        except PortLostError as exc:
            self._lost(exc, now)
            return None
        except CommError as exc:   # retried already: skip this cycle, try again next one
            self.last_error = str(exc)
            self._blind(now)
            return None
        self.bus.stats.cycle_times.append(time.perf_counter() - t0)
        self.cycles += 1
        return self.state

    def _blind(self, now: float) -> None:
        """No state this cycle: a joint in current mode cannot be braked before its limit,
        so it stops pushing (goal current 0) until the state is back."""
        if self._last_goals is None:
            return
        ticks, current = self._last_goals
        blind = [i for i, c in enumerate(self.control)
                 if c == CURRENT and self.bus.modes[i] == OperatingMode.CURRENT and current[i]]
        if not blind:
            return
        current = current.copy()
        current[blind] = 0
        try:
            self.bus.write_goals(ticks, current)   # a sync write: no reply to wait for
            self._last_goals = (ticks, current)
        except PortLostError as exc:
            self._lost(exc, now)
        except CommError:
            pass

    def silent_for(self, now: float | None = None) -> float:
        """Seconds since the last successful sync read (0 while the port is down)."""
        now = time.monotonic() if now is None else now
        return max(0.0, now - self.last_ok) if self.connected else 0.0

    def _torque_dropped(self, before: Sequence[bool]) -> None:
        """Log the servos that turned their torque off by themselves (hardware error)."""
        st = self.state
        assert st is not None
        off = [i for i, (was, is_on) in enumerate(zip(before, self.bus.torque))
               if was and not is_on]
        if off:
            what = [f"{self.config.joints[i].name} "
                    f"({', '.join(decode_hardware_error(int(st.hardware_error[i]))) or 'no error'})"
                    for i in off]
            self._event(f"servo turned its torque off by itself: {', '.join(what)}; "
                        "reboot, then set_torque true", logging.ERROR)

    def _margin(self, speed: np.ndarray, horizon: float) -> np.ndarray:
        """Braking margin (rad) at ``speed`` (rad/s toward a limit, >= 0)."""
        return self.limit_margin + speed * horizon + speed * speed / (2.0 * self.brake_decel)

    def _limit_guard(self, effort: np.ndarray, now: float) -> None:
        """Current mode: brake before a limit (in place on ``effort``, N·m)."""
        st = self.state
        assert st is not None
        dt = now - self._last_apply
        self._last_apply = now
        # the worst recent cycle gap (decaying over ~100 cycles): a host that stalls now and
        # then gets a wider margin
        dt = min(max(dt, 0.002), 0.25) if math.isfinite(dt) else 0.01
        self._gap = max(dt, 0.99 * self._gap)
        horizon = self.brake_cycles * self._gap
        q, v = st.position, st.velocity
        up, down = np.maximum(v, 0.0), np.maximum(-v, 0.0)
        # room left before the margin: torque toward a limit fades out over limit_ramp
        room_up = self.upper - q - self._margin(up, horizon)
        room_down = q - self.lower - self._margin(down, horizon)
        fade_up = np.clip(room_up / self.limit_ramp, 0.0, 1.0)
        fade_down = np.clip(room_down / self.limit_ramp, 0.0, 1.0)
        braked = False
        for i, c in enumerate(self.control):
            if c != CURRENT:
                continue
            if effort[i] > 0.0:
                effort[i] *= fade_up[i]
            elif effort[i] < 0.0:
                effort[i] *= fade_down[i]
            if room_up[i] <= 0.0 and up[i] > BRAKE_MIN_SPEED:
                effort[i], braked = -self.max_effort[i], True
            elif room_down[i] <= 0.0 and down[i] > BRAKE_MIN_SPEED:
                effort[i], braked = self.max_effort[i], True
        self.brakes += braked

    def _apply(self, now: float) -> None:
        """Watchdog, mode switches, limit guard, then the sync write of goals."""
        st = self.state
        assert st is not None
        tripped = [i for i, c in enumerate(self.control)
                   if c == CURRENT and st.bus_watchdog[i] == -1]
        if tripped:
            names = [self.config.joints[i].name for i in tripped]
            self._event(f"bus watchdog: servo of {names} stopped after a silent bus; "
                        "holding position")
            for i in tripped:
                self.effort_stamp[i] = -math.inf    # hold below, like the effort watchdog
        stale = [i for i, c in enumerate(self.control)
                 if c == CURRENT and now - self.effort_stamp[i] > self.command_timeout]
        if stale:
            self.watchdog_trips += 1
            names = [self.config.joints[i].name for i in stale if i not in tripped]
            if names:
                self._event(f"watchdog: no effort command for {self.command_timeout:g} s on "
                            f"{names}; holding position")
            for i in stale:
                self.control[i] = CBP
                self.goal_position[i] = min(max(st.position[i], self.lower[i]), self.upper[i])
                self.goal_effort[i] = self._hold_effort[i]
        effort = np.where([c == CURRENT for c in self.control], self.goal_effort,
                          np.abs(self.goal_effort))
        # the servo ignores position limits in current mode: brake before them
        self._limit_guard(effort, now)
        for i, c in enumerate(self.control):
            if c == CURRENT:   # keep the position goal at the present position (switch back)
                self.goal_position[i] = min(max(st.position[i], self.lower[i]), self.upper[i])
        ticks = self.bus.goal_ticks(self.goal_position)
        current = self.bus.goal_current(effort)
        # limits in cbp/position are unsigned magnitudes; direction applies to torque only
        pos_modes = np.array([c != CURRENT for c in self.control])
        current = np.where(pos_modes, np.abs(current), current)
        for i, c in enumerate(self.control):
            want = OperatingMode.BY_NAME[c]
            if self.bus.modes[i] != want:
                self.bus.set_mode(i, want, int(ticks[i]), int(current[i]))
                self._event(f"{self.config.joints[i].name}: operating mode -> {c}",
                            logging.DEBUG)
        for i in self.bus.restore_torque(st.hardware_error):
            self._event(f"{self.config.joints[i].name}: torque back on after an interrupted "
                        "mode switch", logging.WARNING)
        self.bus.write_goals(ticks, current)
        self._last_goals = (ticks, current)

    # -- diagnostics -------------------------------------------------------------------------
    def diagnostics(self, prefix: str, period: float) -> list[Status]:
        """One status per servo (``<prefix>: <joint>``) and one for the bus (``<prefix>:
        bus``); the error and cycle rates are over the ``period`` s since the last call."""
        out = []
        state = self.state if self.connected else None
        for i, j in enumerate(self.config.joints):
            values = {"id": str(j.id), "model": j.model.name,
                      "mode": OperatingMode.NAMES.get(self.bus.modes[i], "?"),
                      "torque": "on" if self.bus.torque[i] else "off"}
            if state is None:
                level, message = STALE, "port down"
            else:
                bits = int(state.hardware_error[i])
                names = decode_hardware_error(bits)
                values.update(temperature_C=f"{state.temperature[i]:.0f}",
                              voltage_V=f"{state.voltage[i]:.1f}",
                              hardware_error=", ".join(names) or "none",
                              hardware_error_bits=str(bits))
                level = ERROR if bits else OK
                message = f"hardware error: {', '.join(names)}" if bits else "OK"
            out.append(Status(f"{prefix}: {j.name}", f"dxl-{j.id}", level, message,
                              tuple(values.items())))
        stats = self.bus.stats
        tx, fail = stats.transactions - self._window[0], stats.failures - self._window[1]
        self._window = (stats.transactions, stats.failures)
        rate = fail / tx if tx else 0.0
        times = list(stats.cycle_times)
        stats.cycle_times.clear()
        bus_values = {
            "port": self.bus.port_name, "baud": self.bus.baud, "connected": self.connected,
            "sync_read": "fast" if self.bus.fast else "plain", "cycles": self.cycles,
            "cycle_time_ms": f"{1e3 * sum(times) / len(times):.3f}" if times else "n/a",
            "rate_hz": f"{len(times) / period:.1f}",
            "comm_errors": stats.failures, "error_rate": f"{rate:.4f}",
            "reconnects": self.reconnects, "last_error": self.last_error}
        silent = self.silent_for()
        if not self.connected:
            level, message = ERROR, f"port down: {self.last_error}"
        elif silent > 0.5:
            level = ERROR
            message = f"no valid reply from the servos for {silent:.1f} s: {self.last_error}"
        elif rate > 0.01:
            level, message = WARN, f"bus error rate {rate:.1%}"
        else:
            level, message = OK, "OK"
        out.append(Status(f"{prefix}: bus", self.bus.port_name, level, message,
                          tuple((k, str(v)) for k, v in bus_values.items())))
        return out

    # -- services ----------------------------------------------------------------------------
    def in_error(self) -> list[int]:
        if self.state is None:
            return []
        return [i for i, e in enumerate(self.state.hardware_error) if e]

    def hardware_errors(self) -> dict[str, list[str]]:
        """Joint name -> decoded hardware error bits, for the joints in error."""
        if self.state is None:
            return {}
        return {self.config.joints[i].name: decode_hardware_error(int(self.state.hardware_error[i]))
                for i in self.in_error()}

    def set_torque(self, on: bool) -> None:
        """Torque on (holding the present position) or off, for every servo."""
        if not self.connected:
            raise PortLostError(f"port {self.bus.port_name} is down")
        try:
            if on:
                errs = self.hardware_errors()
                if errs:
                    raise CommError("cannot enable torque, hardware error on "
                                    + "; ".join(f"{n}: {', '.join(b)}" for n, b in errs.items())
                                    + " (reboot them first)")
                self.state = self.bus.read_state()
                self._reset_goals_to_present()
                self._apply(time.monotonic())
            self.bus.set_torque(range(len(self.names)), on)
        except PortLostError as exc:
            self._lost(exc, time.monotonic())
            raise

    def reboot(self, names: Sequence[str]) -> list[str]:
        """Reboot the named joints (empty = those in hardware error); returns those rebooted."""
        if not self.connected:
            raise PortLostError(f"port {self.bus.port_name} is down")
        if names:
            unknown = [n for n in names if n not in self.names]
            if unknown:
                raise CommandError(f"unknown joint(s) {unknown}; known: {self.names}")
            indices = [self.config.index(n) for n in names]
        else:
            indices = self.in_error()
        done = []
        try:
            for i in indices:
                self.bus.reboot(i)
                done.append(self.config.joints[i].name)
                self.control[i] = CBP
            self.state = self.bus.read_state()
            for i in indices:
                self.goal_position[i] = min(max(self.state.position[i], self.lower[i]),
                                            self.upper[i])
                self.goal_effort[i] = self._hold_effort[i]
        except PortLostError as exc:
            self._lost(exc, time.monotonic())
            raise
        return done

    def shutdown(self, policy: str) -> None:
        """``hold``: hold the present position, torque on; ``release``: torque off.

        Runs after Ctrl-C, which may have interrupted a transaction: the port is resynced
        first. ``release`` tries every servo even if some fail; if ``hold`` fails, joints in
        current (torque) control are released, since nobody will command them any more.
        """
        if policy not in ("hold", "release"):
            raise ValueError(f"shutdown policy must be hold or release, got {policy!r}")
        if self.connected:
            self.bus.resync()
            if policy == "hold":
                for attempt in range(3):     # (each read already retried twice)
                    try:
                        self.state = self.bus.read_state()
                        self._reset_goals_to_present()
                        self._apply(time.monotonic())
                        break
                    except (PortError, CommError) as exc:
                        if isinstance(exc, PortError) or attempt == 2:
                            _log.warning("shutdown: cannot hold (%s)", exc)
                            self._release([i for i, m in enumerate(self.bus.modes)
                                           if m == OperatingMode.CURRENT])
                            break
            else:
                self._release(range(len(self.names)))
        self.bus.close()
        self.connected = False

    def _release(self, indices: Sequence[int]) -> None:
        """Torque off on each of ``indices``, carrying on past failures (logged)."""
        for i in indices:
            try:
                self.bus.set_torque([i], False)
            except (PortError, CommError) as exc:
                _log.warning("shutdown: %s", exc)
                if isinstance(exc, PortError):
                    return
