"""Following a :class:`~hyperarm_control.trajectory.goal.Trajectory` cycle by cycle (no ROS).

:class:`Follower` turns the trajectory into one position command per control cycle of
``period`` s and judges the arm's measured state against it, as
``joint_trajectory_controller`` does:

- **Path tolerance**: while the trajectory runs, a joint further than its path tolerance
  from the desired position aborts the goal (PATH_TOLERANCE_VIOLATED) and the arm holds
  where it is.
- **Goal tolerance**: after the last point, the goal succeeds once every joint is within
  its goal position (and velocity) tolerance; if that has not happened
  ``goal_time_tolerance`` s after the end, it aborts (GOAL_TOLERANCE_VIOLATED) and holds.
- **Stale state**: a measured state older than ``max_state_age`` s aborts and holds (the
  path cannot be judged on it).
- **Preemption and cancel**: :meth:`Follower.start` replaces a running goal (from the
  present command, no jump); :meth:`Follower.cancel` holds at the last command.

**The invariant**: whatever the trajectory, the state or an abort does, no command moves a
joint further from the previous command than its velocity limit x ``period``, and no
command leaves the joint limits. It is applied last, on every command.

Tolerances follow ``control_msgs/JointTolerance``: a value > 0 is the tolerance, 0 takes the
controller's default, -1 (any negative) means none. Units: rad, rad/s, s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from .errors import GoalToleranceViolated, PathToleranceViolated, TrajectoryError
from .goal import JointLimits, Trajectory

__all__ = ["Tolerances", "Cycle", "Follower", "resolve_tolerance"]


def resolve_tolerance(given: float, default: float) -> float:
    """A JointTolerance value: > 0 as given, 0 the default, < 0 none (inf)."""
    if not math.isfinite(given):
        raise TrajectoryError(f"tolerance {given!r} is not finite")
    return given if given > 0 else (default if given == 0 else math.inf)


@dataclass(frozen=True)
class Tolerances:
    """Per joint (the controller's order): ``path`` and ``goal`` position tolerances (rad),
    ``goal_velocity`` (rad/s), and ``goal_time`` (s after the end)."""

    path: np.ndarray
    goal: np.ndarray
    goal_velocity: np.ndarray
    goal_time: float

    @classmethod
    def resolve(cls, names: Sequence[str], defaults: "Tolerances",
                path: Mapping[str, float] | None = None,
                goal: Mapping[str, float] | None = None,
                goal_velocity: Mapping[str, float] | None = None,
                goal_time: float = 0.0) -> "Tolerances":
        """A goal's tolerances (joint name -> JointTolerance value) over ``defaults``;
        raises :class:`TrajectoryError` (INVALID_GOAL) naming an unknown joint."""
        out = []
        for given, base in ((path, defaults.path), (goal, defaults.goal),
                            (goal_velocity, defaults.goal_velocity)):
            values = base.astype(float).copy()
            for name, value in (given or {}).items():
                if name not in names:
                    raise TrajectoryError(f"tolerance for {name!r}: not a joint of this "
                                          f"controller ({', '.join(names)})")
                i = list(names).index(name)
                values[i] = resolve_tolerance(float(value), float(base[i]))
            out.append(values)
        t = resolve_tolerance(float(goal_time), defaults.goal_time)
        return cls(out[0], out[1], out[2], t)


@dataclass
class Cycle:
    """One control cycle's output: ``command`` (the position to send), the desired
    position/velocity/acceleration, the measured position, their difference ``error``
    (desired - measured), ``status`` ("idle", "running", "succeeded", "aborted",
    "cancelled") and, after an abort, ``failure`` (with its action error code)."""

    command: np.ndarray
    desired: np.ndarray
    desired_velocity: np.ndarray
    desired_acceleration: np.ndarray
    actual: np.ndarray
    error: np.ndarray
    status: str
    failure: TrajectoryError | None = None
    time: float = 0.0


@dataclass
class _Goal:
    traj: Trajectory
    tol: Tolerances
    t0: float
    status: str = "running"
    failure: TrajectoryError | None = None
    done_at: float | None = field(default=None)


class Follower:
    """See the module. ``period`` (s) is the control cycle; ``max_state_age`` (s)."""

    def __init__(self, limits: JointLimits, period: float, max_state_age: float = 0.25
                 ) -> None:
        if not (period > 0 and math.isfinite(period)):
            raise ValueError(f"period must be > 0 s, got {period!r}")
        if not max_state_age > 0:
            raise ValueError(f"max_state_age must be > 0 s, got {max_state_age!r}")
        self.limits = limits
        self.period = period
        self.max_state_age = max_state_age
        self._step = limits.velocity * period
        self._last: np.ndarray | None = None
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
        if q.shape != (n,) or not np.all(np.isfinite(q)):
            raise TrajectoryError(f"measured state: expected {n} finite positions")
        v = np.zeros(n) if v is None else np.asarray(v, dtype=float).reshape(-1)
        if self._last is None:   # the first command starts where the arm is
            self._last = np.clip(q, self.limits.lower, self.limits.upper)
        zeros = np.zeros(n)
        goal = self._goal
        desired, dv, da = (self._hold if self._hold is not None else self._last), zeros, zeros
        if goal is not None and goal.status == "running":
            t = now - goal.t0
            desired, dv, da = goal.traj.sample(t)
            age = now - state_stamp
            if age > self.max_state_age:
                self._abort(goal, PathToleranceViolated(
                    f"joint_states are {age:.3f} s old (more than {self.max_state_age:g} s): "
                    "the path cannot be judged; aborted, holding"), q)
            elif t <= goal.traj.duration:
                err = np.abs(desired - q)
                over = err > goal.tol.path
                if np.any(over):
                    j = int(np.argmax(np.where(over, err - goal.tol.path, -np.inf)))
                    self._abort(goal, PathToleranceViolated(
                        f"{self.limits.names[j]} is {err[j]:.4f} rad from its path at "
                        f"t = {t:.3f} s (path tolerance {goal.tol.path[j]:g}); aborted, "
                        "holding"), q)
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
        command = self._limit(desired)
        return Cycle(command, np.asarray(desired, dtype=float).copy(), dv, da, q,
                     np.asarray(desired, dtype=float) - q, self.goal_status,
                     goal.failure if goal is not None else None,
                     (now - goal.t0) if goal is not None else 0.0)

    def _limit(self, target: np.ndarray) -> np.ndarray:
        """The invariant: within one velocity-limit step of the previous command and
        inside the joint limits."""
        assert self._last is not None
        cmd = np.clip(target, self._last - self._step, self._last + self._step)
        cmd = np.clip(cmd, self.limits.lower, self.limits.upper)
        self._last = cmd
        return cmd.copy()
