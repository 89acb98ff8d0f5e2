"""The sequencing of the host-compensation loop (no ROS): what host_compensation does with
each joint state, enable, disable and silence, on top of :class:`Compensator`.

- One command per joint state while enabled, for the host pose when the arm will be there:
  horizon = the host state's age (the joint state's own age when the host is the rail, the
  host pose's age otherwise) + the measured delay from a command to the joints reaching it
  (:class:`DelayEstimator`, fed after the command is out).
- Enabling needs fresh joint states and a host state; it holds tool0 where it is.
  Disabling, silence of the joint states (``stale_timeout``) or of the host pose stop the
  stream, latched until enabled again.
- The status is judged from the MEASURED tool: FK of the measured arm joints on the host
  pose of their stamp, against the goal. Beyond the config's ``track_position_tolerance``
  or ``track_orientation_tolerance`` for ``off_track_cycles`` states in a row the status is
  ``off_track`` (the reason gives the error and any joint at its limit margin) even when
  the command itself solves the pose; it returns to the command's status after as many
  states within them.
- The period given to the step limit is the difference of the joint states' stamps (their
  arrival times' when unstamped), so a burst of queued states does not widen the step.
- Status changes (unreachable, off track, reachable again, stopped) come back as
  ``(level, text)`` log lines, level ``"warn"`` or ``"info"``.

Times in s on one clock (the node's); ``stamp`` values are the messages' header stamps.
"""
from __future__ import annotations

import math

import numpy as np

from ..own_gap import OwnGap
from .compensation import Compensator, DelayEstimator, HostState, Status

__all__ = ["CompensationLoop"]

Log = list[tuple[str, str]]


class CompensationLoop:
    """``host_from_states``: the host state comes with the joint states (the rail), so its
    age is theirs; else it is a host pose with a stamp of its own."""

    def __init__(self, comp: Compensator, delay: DelayEstimator, stale_timeout: float,
                 host_from_states: bool, off_track_cycles: int = 3) -> None:
        self.comp, self.delay = comp, delay
        self.stale_timeout = float(stale_timeout)
        self.host_from_states = host_from_states
        self.enabled = False
        self.status, self.reason = "disabled", "disabled"
        self.cycles = 0                    # commands since enabled
        self.states = 0                    # joint states received while enabled
        self.latency = 0.0                 # s, smoothed age of the joint states on arrival
        self.last_state: float | None = None   # s, arrival of the last joint state
        self._own_gap = OwnGap(self.stale_timeout)   # between check_stale calls
        self._host_grace = -math.inf           # s, host pose not judged stale before this
        self.error = (0.0, 0.0)            # m, rad of the last command (predicted goal)
        self.measured = (0.0, 0.0)         # m, rad of the measured tool against the goal
        self.off_track_cycles = int(off_track_cycles)
        self._off, self._on = 0, 0         # states in a row beyond / within the tolerances
        self.off_track = 0                 # states judged beyond the tolerances since enable
        self.last_stamp = 0.0              # s, header stamp of the last joint state

    def on_state(self, now: float, stamp: float, q: np.ndarray, host: HostState | None,
                 host_stamp: float | None, host_arrival: float | None,
                 measured_host: HostState | None = None) -> tuple[np.ndarray | None, Log]:
        """A joint state (arm joints ``q`` rad, header ``stamp`` s, 0 = unknown) arrived at
        ``now``: the command to send (None: none) and the log lines. ``measured_host``: the
        host state that judges the measured tool (default ``host``; the unfiltered one
        where ``host`` is filtered)."""
        age = min(max(now - stamp, 0.0), 0.5) if stamp > 0.0 else 0.0
        command, log = None, []
        # this process not run for stale_timeout s (a loaded machine's scheduling): the
        # host pose's silence across that gap is the node's own, and its queued host poses
        # may be read only after several queued states: the host pose gets stale_timeout
        # from here to arrive (cycles meanwhile use the last one, its age in the horizon)
        if self.last_state is not None and now - self.last_state > self.stale_timeout:
            self._host_grace = now + self.stale_timeout
        judged = now >= self._host_grace
        if self.enabled:
            self.states += 1
            if host is None or (not self.host_from_states and judged and (
                    host_arrival is None or now - host_arrival > self.stale_timeout)):
                log += self.disable("host pose stale or missing: compensation stopped")
            else:
                if stamp > 0.0 and 0.0 < self.last_stamp < stamp:
                    dt = stamp - self.last_stamp
                else:
                    dt = now - self.last_state if self.last_state is not None else 0.01
                measured = self._measured(q, host if measured_host is None else measured_host,
                                          stamp, host_stamp)
                command, log = self._cycle(now, age, host, host_stamp, dt, q, measured)
                self.delay.measured(now - age, q)      # when the joints were there
        self.latency += 0.1 * (age - self.latency)
        self.last_state = now
        if stamp > 0.0:
            self.last_stamp = stamp
        return command, log

    def _measured(self, q: np.ndarray, host: HostState, stamp: float,
                  host_stamp: float | None) -> tuple[float, float]:
        """(m, rad) the measured tool against the goal, the host taken at the joint
        state's stamp (the rail's own state; a host pose moved on by its twist)."""
        if not self.host_from_states and host_stamp is not None and stamp > 0.0:
            host = HostState.trusted(host.predict(min(max(stamp - host_stamp, -0.5), 0.5)),
                                     host.linear, host.angular)
        return self.comp.measured_error(q, host)

    def _cycle(self, now: float, age: float, host: HostState, host_stamp: float | None,
               dt: float, q: np.ndarray, measured: tuple[float, float]
               ) -> tuple[np.ndarray, Log]:
        dt = min(max(dt, 1e-3), 0.1)
        h_age = age if self.host_from_states or host_stamp is None else \
            min(max(now - host_stamp, 0.0), 0.5)
        step = self.comp.step(host, h_age + self.delay.delay, dt)
        self.cycles += 1
        self.error = (step.position_error, step.orientation_error)
        self.measured = measured
        c = self.comp.config
        beyond = measured[0] > c.track_position_tolerance \
            or measured[1] > c.track_orientation_tolerance
        self._off, self._on = (self._off + 1, 0) if beyond else (0, self._on + 1)
        self.off_track += beyond
        status, reason = step.status, step.reason
        stays_off = self.status == Status.OFF_TRACK.value and self._on < self.off_track_cycles
        if status is not Status.UNREACHABLE and (self._off >= self.off_track_cycles
                                                 or stays_off):
            limits = self.comp.limit_joints(q, 0.01)
            reason = (f"measured tool {measured[0] * 1e3:.1f} mm, "
                      f"{math.degrees(measured[1]):.2f} deg off the goal (tolerance "
                      f"{c.track_position_tolerance * 1e3:g} mm, "
                      f"{math.degrees(c.track_orientation_tolerance):g} deg)"
                      + (f"; at the limit margin: {', '.join(limits)}" if limits else ""))
            status = Status.OFF_TRACK
        log: Log = []
        if status.value != self.status:
            if status in (Status.UNREACHABLE, Status.OFF_TRACK):
                log.append(("warn", reason))
            elif self.status == Status.UNREACHABLE.value:
                log.append(("info", f"goal reachable again: {status.value}"))
            elif self.status == Status.OFF_TRACK.value:
                log.append(("info", f"back on track: {status.value}"))
        if status.value != self.status or status is Status.OFF_TRACK:
            self.status, self.reason = status.value, reason or status.value
        self.delay.commanded(now, step.q)
        return step.command, log

    def enable(self, now: float, q: np.ndarray | None, host: HostState | None,
               source: str) -> tuple[bool, str, np.ndarray | None]:
        """(success, message, goal): hold tool0 where it is now (FK of ``q`` on ``host``)."""
        fresh = self.last_state is not None and now - self.last_state <= self.stale_timeout
        if not fresh or q is None:
            return False, "cannot enable: no fresh joint_states", None
        if host is None:
            return False, f"cannot enable: no host pose yet ({source})", None
        goal = self.comp.start(q, host)
        self.delay.reset()
        self.cycles = self.states = self.off_track = 0
        self._off = self._on = 0
        self.enabled, self.status, self.reason = True, "tracking", "enabled"
        return True, "", goal

    def disable(self, why: str) -> Log:
        log: Log = [("warn", f"host compensation off: {why}")] if self.enabled else []
        self.enabled, self.status, self.reason = False, "disabled", why
        self.comp.stop()
        return log

    def check_stale(self, now: float) -> Log:
        """Joint states stopped while enabled: stop (latched) rather than resume later from
        an old command. Not judged right after this process itself did not run for
        ``stale_timeout`` s (no check since: a loaded machine's scheduling): the states
        queued meanwhile are read first, and the next check judges."""
        if self._own_gap.after_gap(now):
            return []
        if self.enabled and self.last_state is not None \
                and now - self.last_state > self.stale_timeout:
            return self.disable(f"no joint_states for {self.stale_timeout:g} s: "
                                "compensation stopped")
        return []

    def diagnostics(self) -> dict[str, object]:
        """Figures for the node's diagnostics (status, counts, ms)."""
        return {"enabled": self.enabled, "status": self.status, "reason": self.reason,
                "cycles": self.cycles, "states": self.states, "latency_ms": f"{self.latency * 1e3:.2f}",
                "loop_delay_ms": f"{self.delay.delay * 1e3:.2f}",
                "position_error_m": f"{self.error[0]:.5f}",
                "orientation_error_rad": f"{self.error[1]:.5f}",
                "measured_position_error_m": f"{self.measured[0]:.5f}",
                "measured_orientation_error_rad": f"{self.measured[1]:.5f}",
                "off_track_states": self.off_track}
