"""Following a :class:`~hyperarm_control.trajectory.goal.Trajectory` cycle by cycle (no ROS).

:class:`Follower` turns the trajectory into one position command per control cycle of
``period`` s and judges the arm's measured state against it, as
``joint_trajectory_controller`` does:

- **Path tolerance**: while the trajectory runs, a joint further than its path tolerance
  from the desired position aborts the goal (PATH_TOLERANCE_VIOLATED) and the arm holds
  where it is. The measured state is judged against the trajectory at the instant it was
  measured (its stamp), not at the cycle's time: the error is the arm's, not the age of the
  message that reports it.
- **Command lead**: each command is the trajectory ``command_lead`` s ahead of the cycle's
  time, so that the servos, which reach a goal position with a delay (their position loop,
  the bus and the driver's cycle), are where the trajectory is when it is there. 0 sends the
  trajectory's present position, as joint_trajectory_controller's position interface does.
- **Profile lead**: servos that run an acceleration-limited profile towards each goal
  (Dynamixel Profile Acceleration, as dynamixel_driver writes it; the PMAC's jog) brake to
  stop at the goal, so they trail a goal moving at v by v|v| / (2 a). With
  ``profile_acceleration`` given (per joint, rad/s²), each command adds that distance for
  the trajectory's velocity at the commanded instant: the servo's own braking curve then
  ends where the trajectory goes, and as the trajectory slows down the lead shrinks to 0
  at its end.
- **Goal tolerance**: after the last point, the goal succeeds once every joint is within
  its goal position (and velocity) tolerance; if that has not happened
  ``goal_time_tolerance`` s after the end, it aborts (GOAL_TOLERANCE_VIOLATED) and holds.
- **Stale state**: a measured state older than ``max_state_age`` s aborts and holds the
  last command (the path cannot be judged on it, and the arm is not sent back to where the
  old state says it was).
- **Preemption and cancel**: :meth:`Follower.start` replaces a running goal (from the
  present command, no jump); :meth:`Follower.cancel` holds at the last command;
  :meth:`Follower.release` (the controller stops commanding) drops the hold;
  :meth:`Follower.reseed` makes the next goal start from the arm's measured position when
  another commander moved it (the caller decides when).

**The invariant**: whatever the trajectory, the state or an abort does, no command moves a
joint further from the previous command than its velocity limit x the time since it (at
most ``period``), and no command leaves the joint limits. It is applied last, on every
command.

Tolerances follow ``control_msgs/JointTolerance`` as joint_trajectory_controller reads them:
a value > 0 is the tolerance, 0 takes the controller's default, -1 means none, any other
negative value is refused; a resolved 0 is not checked. Units: rad, rad/s, s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from hyperarm_description.limits import limit_step

from .errors import (GoalToleranceViolated, InvalidGoal, PathToleranceViolated,
                     TrajectoryError)
from .goal import JointLimits, Trajectory

__all__ = ["Tolerances", "Cycle", "Follower", "resolve_tolerance"]


def resolve_tolerance(given: float, default: float) -> float:
    """A JointTolerance value: > 0 as given, 0 the default, -1 none (inf); other negative
    values are refused (INVALID_GOAL), as joint_trajectory_controller does."""
    if not math.isfinite(given) or (given < 0 and given != -1.0):
        raise InvalidGoal(f"tolerance {given!r}: > 0, 0 (the default) or -1 (none)")
    return given if given > 0 else (default if given == 0 else math.inf)


def _unchecked_if_zero(values: np.ndarray) -> np.ndarray:
    out = np.asarray(values, dtype=float).copy()
    out[out == 0.0] = math.inf
    return out


@dataclass(frozen=True)
class Tolerances:
    """Per joint (the controller's order): ``path`` position (rad) and ``path_velocity``
    (rad/s) tolerances while the trajectory runs, ``goal`` position and ``goal_velocity``
    tolerances at its end, and ``goal_time`` (s after the end). As in
    joint_trajectory_controller, 0 means not checked (stored as inf) and a ``goal_time`` of
    0 waits for the goal without limit. (JointTolerance's acceleration is not checked: the
    drivers do not measure accelerations.)"""

    path: np.ndarray
    path_velocity: np.ndarray
    goal: np.ndarray
    goal_velocity: np.ndarray
    goal_time: float

    def __post_init__(self) -> None:
        for name in ("path", "path_velocity", "goal", "goal_velocity"):
            values = np.asarray(getattr(self, name), dtype=float)
            if np.any(values < 0) or np.any(np.isnan(values)):
                raise ValueError(f"{name}: tolerances must be >= 0 (0 = not checked)")
            object.__setattr__(self, name, _unchecked_if_zero(values))
        if not self.goal_time >= 0:
            raise ValueError(f"goal_time must be >= 0 s, got {self.goal_time!r}")
        if self.goal_time == 0.0:
            object.__setattr__(self, "goal_time", math.inf)

    @classmethod
    def resolve(cls, names: Sequence[str], defaults: "Tolerances",
                path: Mapping[str, tuple[float, float]] | None = None,
                goal: Mapping[str, tuple[float, float]] | None = None,
                goal_time: float = 0.0) -> "Tolerances":
        """A goal's tolerances over ``defaults``: ``path`` and ``goal`` map a joint name to
        its JointTolerance (position, velocity) values. Raises :class:`InvalidGoal` naming
        an unknown joint or an illegal value."""
        out = {"path": defaults.path.copy(), "path_velocity": defaults.path_velocity.copy(),
               "goal": defaults.goal.copy(), "goal_velocity": defaults.goal_velocity.copy()}
        for given, (pos_key, vel_key) in ((path, ("path", "path_velocity")),
                                          (goal, ("goal", "goal_velocity"))):
            for name, (position, velocity) in (given or {}).items():
                if name not in names:
                    raise InvalidGoal(f"tolerance for {name!r}: not a joint of this "
                                      f"controller ({', '.join(names)})")
                i = list(names).index(name)
                for key, value in ((pos_key, position), (vel_key, velocity)):
                    try:
                        out[key][i] = resolve_tolerance(float(value), out[key][i])
                    except InvalidGoal as exc:
                        what = key.replace("_", " ")
                        raise InvalidGoal(f"{name}: {what} {exc}") from None
        if not math.isfinite(goal_time) or (goal_time < 0 and goal_time != -1.0):
            raise InvalidGoal(f"goal_time_tolerance {goal_time!r}: >= 0 or -1")
        t = defaults.goal_time if goal_time == 0 else (math.inf if goal_time < 0
                                                       else goal_time)
        return cls(out["path"], out["path_velocity"], out["goal"], out["goal_velocity"], t)


@dataclass
class Cycle:
    """One control cycle's output: ``command`` (the position to send: ``target`` after
    the per-cycle step limit), the desired position/velocity/acceleration at ``time`` (s
    from the goal's start: the measured state's stamp), the measured position ``actual``,
    their difference ``error`` (desired - measured), ``status`` ("idle", "running",
    "succeeded", "aborted", "cancelled") and, after an abort, ``failure`` (with its action
    error code). ``target``: the trajectory ``command_lead`` s ahead, or the hold."""

    command: np.ndarray
    desired: np.ndarray
    desired_velocity: np.ndarray
    desired_acceleration: np.ndarray
    actual: np.ndarray
    error: np.ndarray
    status: str
    failure: TrajectoryError | None = None
    time: float = 0.0
    target: np.ndarray | None = None


@dataclass
class _Goal:
    traj: Trajectory
    tol: Tolerances
    t0: float
    status: str = "running"
    failure: TrajectoryError | None = None
    done_at: float | None = field(default=None)


class Follower:
    """See the module. ``period`` (s) is the control cycle; ``max_state_age`` (s);
    ``command_lead`` (s, >= 0) how far ahead of the cycle's time commands are sampled;
    ``profile_acceleration`` (rad/s² per joint, > 0) the servos' profile acceleration for
    the profile lead, or None for none."""

    def __init__(self, limits: JointLimits, period: float, max_state_age: float = 0.25,
                 command_lead: float = 0.0,
                 profile_acceleration: np.ndarray | None = None) -> None:
        if not (period > 0 and math.isfinite(period)):
            raise ValueError(f"period must be > 0 s, got {period!r}")
        if not max_state_age > 0:
            raise ValueError(f"max_state_age must be > 0 s, got {max_state_age!r}")
        if not (0.0 <= command_lead <= 1.0):
            raise ValueError(f"command_lead must be in [0, 1] s, got {command_lead!r}")
        self.limits = limits
        self.period = period
        self.max_state_age = max_state_age
        self.command_lead = command_lead
        if profile_acceleration is not None:
            profile_acceleration = np.asarray(profile_acceleration, dtype=float).reshape(-1)
            if (profile_acceleration.shape != limits.velocity.shape
                    or not np.all(profile_acceleration > 0)
                    or not np.all(np.isfinite(profile_acceleration))):
                raise ValueError(f"profile_acceleration: {len(limits.names)} finite values > 0"
                                 f" rad/s², got {profile_acceleration.tolist()}")
        self.profile_acceleration = profile_acceleration
        self._last: np.ndarray | None = None
        self._last_now: float | None = None     # the cycle time of the last command, s
        self._hold: np.ndarray | None = None
        self._goal: _Goal | None = None

    @property
    def goal_status(self) -> str:
        return "idle" if self._goal is None else self._goal.status

    def start(self, traj: Trajectory, tolerances: Tolerances, now: float) -> None:
        """Follow ``traj`` from ``now`` (s); a running goal is replaced (preempted)."""
        if traj.names != self.limits.names:
            raise TrajectoryError("trajectory joints differ from the controller's")
        self._goal = _Goal(traj, tolerances, now)
        self._hold = None

    def cancel(self) -> None:
        """Stop following: hold at the last command."""
        if self._goal is not None and self._goal.status == "running":
            self._goal.status = "cancelled"
        self._hold = self._last.copy() if self._last is not None else None

    @property
    def last_command(self) -> np.ndarray | None:
        """The last command given (a copy), or None before the first."""
        return None if self._last is None else self._last.copy()

    def release(self) -> None:
        """The controller stops commanding (its hold is reached): no hold is kept. The next
        goal's commands continue from the last command (the invariant holds across goals)
        unless :meth:`reseed` says the arm is elsewhere."""
        if self._goal is not None and self._goal.status == "running":
            raise TrajectoryError("release() while a goal runs")
        self._hold = None

    def reseed(self, q: np.ndarray) -> None:
        """Between goals: the arm is at ``q`` (rad), not where this follower left it (another
        commander moved it): the next commands start from ``q`` (clipped to the limits),
        not one velocity step at a time from the old last command."""
        if self._goal is not None and self._goal.status == "running":
            raise TrajectoryError("reseed() while a goal runs")
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != self.limits.velocity.shape or not np.all(np.isfinite(q)):
            raise TrajectoryError(f"reseed: expected {len(self.limits.names)} finite "
                                  "positions")
        self._last = np.clip(q, self.limits.lower, self.limits.upper)
        self._hold = None

    def _abort(self, goal: _Goal, failure: TrajectoryError, q: np.ndarray) -> None:
        goal.status = "aborted"
        goal.failure = failure
        self._hold = q.copy()     # hold where the arm is

    def step(self, now: float, q: np.ndarray, state_stamp: float,
             v: np.ndarray | None = None) -> Cycle:
        """One cycle at ``now`` (s) with the measured positions ``q`` (and velocities ``v``)
        stamped ``state_stamp`` (s, same clock)."""
        q = np.asarray(q, dtype=float).reshape(-1)
        n = len(self.limits.names)
        v = np.zeros(n) if v is None else np.asarray(v, dtype=float).reshape(-1)
        if q.shape != (n,) or v.shape != (n,) or not np.all(np.isfinite(q + v)):
            raise TrajectoryError(f"measured state: expected {n} finite positions and "
                                  "velocities")
        if not (math.isfinite(now) and math.isfinite(state_stamp)):
            raise TrajectoryError(f"times must be finite (now {now!r}, stamp "
                                  f"{state_stamp!r})")
        if self._last is None:   # the first command starts where the arm is
            self._last = np.clip(q, self.limits.lower, self.limits.upper)
        zeros = np.zeros(n)
        goal = self._goal
        desired, dv, da = (self._hold if self._hold is not None else self._last), zeros, zeros
        target = desired
        t_state = 0.0
        if goal is not None and goal.status == "running":
            t = now - goal.t0
            t_state = min(state_stamp - goal.t0, t)   # judged where the state was measured
            target, tv, _ = goal.traj.sample(t + self.command_lead)
            if self.profile_acceleration is not None:
                target = target + tv * np.abs(tv) / (2.0 * self.profile_acceleration)
            desired, dv, da = goal.traj.sample(t_state)
            age = now - state_stamp
            if age > self.max_state_age:   # the measurement is old: hold the command
                self._abort(goal, PathToleranceViolated(
                    f"joint_states are {age:.3f} s old (more than {self.max_state_age:g} s): "
                    "the path cannot be judged; aborted, holding"), self._last)
            elif t <= goal.traj.duration:
                err = np.abs(desired - q)
                verr = np.abs(dv - v)
                over = err > goal.tol.path
                vover = verr > goal.tol.path_velocity
                if np.any(over):
                    j = int(np.argmax(np.where(over, err - goal.tol.path, -np.inf)))
                    self._abort(goal, PathToleranceViolated(
                        f"{self.limits.names[j]} is {err[j]:.4f} rad from its path at "
                        f"t = {t:.3f} s (path tolerance {goal.tol.path[j]:g}); aborted, "
                        "holding"), q)
                elif np.any(vover):
                    j = int(np.argmax(np.where(vover, verr - goal.tol.path_velocity,
                                               -np.inf)))
                    self._abort(goal, PathToleranceViolated(
                        f"{self.limits.names[j]} moves {verr[j]:.4f} rad/s off its path's "
                        f"velocity at t = {t:.3f} s (path velocity tolerance "
                        f"{goal.tol.path_velocity[j]:g}); aborted, holding"), q)
            else:
                within = (np.all(np.abs(goal.traj.goal - q) <= goal.tol.goal)
                          and np.all(np.abs(v) <= goal.tol.goal_velocity))
                if within:
                    goal.status = "succeeded"
                    goal.done_at = now
                    self._hold = goal.traj.goal.copy()
                elif t > goal.traj.duration + goal.tol.goal_time:
                    err = np.abs(goal.traj.goal - q)
                    j = int(np.argmax(err - goal.tol.goal))
                    self._abort(goal, GoalToleranceViolated(
                        f"{self.limits.names[j]} is {err[j]:.4f} rad from its goal "
                        f"{t - goal.traj.duration:.3f} s after the end (goal tolerance "
                        f"{goal.tol.goal[j]:g}, goal_time_tolerance "
                        f"{goal.tol.goal_time:g} s); aborted, holding"), q)
            if goal.status != "running":
                desired, dv, da = self._hold, zeros, zeros
                target = desired
        # the step limit by the time since the last command (at most one period): cycles
        # that come early (a driver's burst) do not move the arm faster than its limits
        gap = self.period if self._last_now is None else min(max(now - self._last_now, 0.0),
                                                                self.period)
        command = self._limit(target, gap)
        self._last_now = now
        return Cycle(command, np.asarray(desired, dtype=float).copy(), dv, da, q,
                     np.asarray(desired, dtype=float) - q, self.goal_status,
                     goal.failure if goal is not None else None, t_state,
                     np.asarray(target, dtype=float).copy())

    def _limit(self, target: np.ndarray, gap: float) -> np.ndarray:
        """The invariant: within velocity limit x ``gap`` (s, at most one period) of the
        previous command and inside the joint limits."""
        assert self._last is not None
        if not np.all(np.isfinite(target)):
            raise TrajectoryError(f"non-finite command {np.asarray(target).tolist()}")
        if gap > 0.0:        # the project's step limit (hyperarm_description.limits)
            cmd = limit_step(target, self._last, self.limits.velocity,
                             min(gap, self.period), self.limits.lower, self.limits.upper)
        else:                # no time since the last command: no step
            cmd = self._last.copy()
        self._last = cmd
        return cmd.copy()
