"""A joint trajectory goal checked and turned into splines (no ROS; rad, rad/s, rad/s², s).

What ``control_msgs/FollowJointTrajectory`` and ``trajectory_msgs/JointTrajectory`` carry,
as plain arrays: joint names, points' ``time_from_start`` and positions, optionally
velocities and accelerations. :func:`build_trajectory` checks a goal the way
``joint_trajectory_controller`` documents it and then against the robot's limits, and
returns a :class:`Trajectory` that starts from the arm's present state:

- positions only: a C2 cubic spline through the points (``scipy.interpolate.CubicSpline``),
  clamped to the present velocity at the start and to rest at the end;
- positions and velocities: cubic Hermite segments; with accelerations too: quintic
  segments (``scipy.interpolate.BPoly.from_derivatives``).

A first point at ``time_from_start`` 0 is the start state MoveIt puts first: it must lie
within ``start_tolerance`` of the present position, and the spline starts from the present
position, not from it (no jump). The spline, sampled every ``check_period`` s, must stay
within the position, velocity and acceleration limits: a goal that asks more than the
joints can do is refused before it runs, naming the joint, the time and the value.
Every refusal is a :class:`~hyperarm_control.trajectory.errors.TrajectoryError` carrying
the action's error code.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.interpolate import BPoly, CubicSpline

from .errors import InvalidGoal, InvalidJoints, OldHeaderTimestamp

__all__ = ["JointLimits", "Trajectory", "build_trajectory", "start_time"]


@dataclass(frozen=True)
class JointLimits:
    """The controlled joints, in the controller's order, and their limits: ``lower``,
    ``upper`` (rad, m for a rail), ``velocity`` (rad/s), ``acceleration`` (rad/s²)."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.names)
        if n == 0 or len(set(self.names)) != n:
            raise ValueError(f"names: {n} joints, {len(set(self.names))} distinct")
        for field in ("lower", "upper", "velocity", "acceleration"):
            value = np.asarray(getattr(self, field), dtype=float).reshape(-1)
            if value.shape != (n,) or not np.all(np.isfinite(value)):
                raise ValueError(f"{field}: expected {n} finite values, got {value.tolist()}")
            object.__setattr__(self, field, value)
        if np.any(self.lower >= self.upper):
            raise ValueError("lower must be below upper for every joint")
        if np.any(self.velocity <= 0) or np.any(self.acceleration <= 0):
            raise ValueError("velocity and acceleration limits must be > 0")

    @classmethod
    def from_description(cls, desc) -> "JointLimits":
        """The arm's joints (and the rail first, on rail_arm) of a
        :class:`~hyperarm_description.model.RobotDescription`."""
        joints = list(desc.joints)
        rows = ([(desc.rail.name, desc.rail.lower, desc.rail.upper, desc.rail.velocity,
                  desc.rail.acceleration)] if desc.rail else [])
        rows += [(j.name, j.lower, j.upper, j.velocity, j.acceleration) for j in joints]
        names, lo, hi, vel, acc = zip(*rows)
        return cls(tuple(names), np.array(lo), np.array(hi), np.array(vel), np.array(acc))


@dataclass(frozen=True)
class Trajectory:
    """Splines of all joints from t = 0 (the start state) to ``duration`` s; held at the
    last point after it. ``kind``: "cubic" (positions only), "hermite" (with velocities),
    "quintic" (with accelerations) or "hold" (stay at the present position)."""

    names: tuple[str, ...]
    knots: np.ndarray
    kind: str
    _spline: CubicSpline | BPoly | None
    goal: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.knots[-1])

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, velocity, acceleration) of every joint at ``t`` s after the start."""
        if self._spline is None or t >= self.duration:
            return self.goal.copy(), np.zeros_like(self.goal), np.zeros_like(self.goal)
        t = max(t, 0.0)
        s = self._spline
        return np.asarray(s(t)), np.asarray(s(t, 1)), np.asarray(s(t, 2))


#: rad/s: a last point's velocity at most this is at rest (float32's epsilon, as
#: joint_trajectory_controller's check)
REST_VELOCITY = float(np.finfo(np.float32).eps)


def _array(values: Sequence[Sequence[float]] | None, n_points: int, n: int,
           what: str) -> np.ndarray | None:
    """Per-point arrays of one kind: all points have ``n`` values, or none has any."""
    if values is None:
        return None
    if all(len(v) == 0 for v in values):
        return None
    if len(values) != n_points:
        raise InvalidGoal(f"{what}: {len(values)} entries for {n_points} points")
    for i, v in enumerate(values):
        if len(v) != n:
            raise InvalidGoal(f"{what}: point {i} has {len(v)} values, expected {n} for "
                              "every point or none")
    out = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(out)):
        i, j = np.argwhere(~np.isfinite(out))[0]
        raise InvalidGoal(f"{what}: point {i} has {out[i, j]} for joint {j}")
    return out


def build_trajectory(limits: JointLimits, joint_names: Sequence[str],
                     times: Sequence[float], positions: Sequence[Sequence[float]],
                     velocities: Sequence[Sequence[float]] | None = None,
                     accelerations: Sequence[Sequence[float]] | None = None, *,
                     start_position: np.ndarray, start_velocity: np.ndarray | None = None,
                     elapsed: float = 0.0, start_tolerance: float = 0.05,
                     check_period: float = 0.002, max_duration: float = 3600.0
                     ) -> Trajectory:
    """Check a goal (see the module) and build its splines from the present state
    (``start_position``, ``start_velocity``: the controller's joint order; a position
    outside the limits is taken as the nearest limit, as the follower's first command is).

    ``elapsed`` (s): how long ago the goal's time origin was (now - header.stamp for a
    stamp in the past, see :func:`start_time`): as joint_trajectory_controller does, points
    already due are dropped and the present state is put at the present instant, so the
    trajectory's t = 0 is now. A goal longer than ``max_duration`` s is refused."""
    names = list(joint_names)
    unknown = [n for n in names if n not in limits.names]
    dup = sorted({n for n in names if names.count(n) > 1})
    missing = [n for n in limits.names if n not in names]
    if unknown or dup or missing:
        parts = ([f"unknown {', '.join(unknown)}"] if unknown else []) + \
                ([f"repeated {', '.join(dup)}"] if dup else []) + \
                ([f"missing {', '.join(missing)}"] if missing else [])
        raise InvalidJoints(f"joint_names: {'; '.join(parts)} (this controller takes exactly "
                            f"{', '.join(limits.names)})")
    n = len(names)
    order = [names.index(j) for j in limits.names]   # message order -> controller order
    if len(positions) == 0:
        raise InvalidGoal("points: empty (nothing to follow)")
    t = np.asarray(times, dtype=float).reshape(-1)
    if t.shape[0] != len(positions):
        raise InvalidGoal(f"points: {t.shape[0]} times for {len(positions)} points")
    if not np.all(np.isfinite(t)):
        raise InvalidGoal(f"time_from_start: point {int(np.argmax(~np.isfinite(t)))} is "
                          "not finite")
    if t[0] < 0.0:
        raise InvalidGoal(f"time_from_start: point 0 at {t[0]:g} s, before the start")
    if t[-1] > max_duration:
        raise InvalidGoal(f"time_from_start: the last point at {t[-1]:g} s is beyond "
                          f"{max_duration:g} s (send long motions in parts)")
    if np.any(np.diff(t) <= 0.0):
        i = int(np.argmax(np.diff(t) <= 0.0)) + 1
        raise InvalidGoal(f"time_from_start: point {i} at {t[i]:g} s is not after point "
                          f"{i - 1} at {t[i - 1]:g} s (times must increase strictly)")
    p = _array(positions, len(t), n, "positions")
    if p is None:
        raise InvalidGoal("positions: every point needs one per joint")
    v = _array(velocities, len(t), n, "velocities")
    a = _array(accelerations, len(t), n, "accelerations")
    if a is not None and v is None:
        raise InvalidGoal("accelerations without velocities (give both, or positions only)")
    # joint_trajectory_controller compares with float's epsilon: a velocity computed as
    # -6e-16 is at rest
    if v is not None and np.any(np.abs(v[-1]) > REST_VELOCITY):
        j = int(np.argmax(np.abs(v[-1]) > REST_VELOCITY))
        raise InvalidGoal(f"velocities: the last point gives {names[j]} {v[-1, j]:g} rad/s; "
                          "a trajectory must end at rest (as joint_trajectory_controller's "
                          "default allow_nonzero_velocity_at_trajectory_end: false)")
    p = p[:, order]
    v = v[:, order] if v is not None else None
    a = a[:, order] if a is not None else None
    for arr, lo, hi, what in ((p, limits.lower, limits.upper, "positions"),
                              (v, -limits.velocity, limits.velocity, "velocities"),
                              (a, -limits.acceleration, limits.acceleration,
                               "accelerations")):
        if arr is None:
            continue
        bad = np.argwhere((arr < lo) | (arr > hi))
        if bad.size:
            i, j = bad[0]
            raise InvalidGoal(f"{what}: point {i}, {limits.names[j]} = {arr[i, j]:.6g} is "
                              f"outside its limits [{lo[j]:.6g}, {hi[j]:.6g}]")
    q0 = np.asarray(start_position, dtype=float).reshape(-1)
    v0 = (np.zeros(n) if start_velocity is None
          else np.asarray(start_velocity, dtype=float).reshape(-1))
    if q0.shape != (n,) or v0.shape != (n,) or not np.all(np.isfinite(q0 + v0)):
        raise InvalidGoal(f"the present state: expected {n} finite positions and velocities")
    if not (elapsed >= 0.0 and math.isfinite(elapsed)):
        raise InvalidGoal(f"elapsed must be >= 0 s, got {elapsed!r}")
    q0 = np.clip(q0, limits.lower, limits.upper)
    if elapsed > 0.0:   # a late start: the points already due are dropped
        due = t <= elapsed
        if np.all(due):
            raise OldHeaderTimestamp(f"every point was due {elapsed:.3f} s after the stamp, "
                                     "which is past")
        t, p = t[~due] - elapsed, p[~due]
        v = v[~due] if v is not None else None
        a = a[~due] if a is not None else None
    elif t[0] == 0.0:     # the start state MoveIt sends first
        off = np.abs(p[0] - q0)
        if np.any(off > start_tolerance):
            j = int(np.argmax(off))
            raise InvalidGoal(f"point 0 at t = 0 puts {limits.names[j]} at {p[0, j]:.4f}, "
                              f"{off[j]:.4f} from where it is ({q0[j]:.4f}; start tolerance "
                              f"{start_tolerance:g})")
        t, p = t[1:], p[1:]
        v = v[1:] if v is not None else None
        a = a[1:] if a is not None else None
        if t.size == 0:   # only the start state: hold where the arm is
            return Trajectory(tuple(limits.names), np.zeros(1), "hold", None, q0.copy())
    knots = np.concatenate([[0.0], t])
    pos = np.vstack([q0, p])
    if v is None:
        spline: CubicSpline | BPoly = CubicSpline(knots, pos, axis=0,
                                                  bc_type=((1, v0), (1, np.zeros(n))))
        kind = "cubic"
    else:
        vel = np.vstack([v0, v])
        if a is None:
            data = np.stack([pos, vel], axis=1)
            kind = "hermite"
        else:
            data = np.stack([pos, vel, np.vstack([np.zeros(n), a])], axis=1)
            kind = "quintic"
        spline = BPoly.from_derivatives(knots, data)
    traj = Trajectory(tuple(limits.names), knots, kind, spline, pos[-1].copy())
    _check_limits(traj, limits, check_period)
    return traj


def _check_limits(traj: Trajectory, limits: JointLimits, period: float) -> None:
    """Refuse a spline that leaves the position, velocity or acceleration limits anywhere
    (sampled every ``period`` s and at the knots)."""
    period = max(period, traj.duration / 200_000.0)    # at most 200k samples (memory)
    count = max(2, int(math.ceil(traj.duration / period)) + 1)
    ts = np.unique(np.concatenate([np.linspace(0.0, traj.duration, count), traj.knots]))
    s = traj._spline
    tol = 1e-9
    for nu, lo, hi, what in ((0, limits.lower, limits.upper, "position"),
                             (1, -limits.velocity, limits.velocity, "velocity"),
                             (2, -limits.acceleration, limits.acceleration, "acceleration")):
        values = np.asarray(s(ts, nu))
        bad = np.argwhere((values < lo - tol) | (values > hi + tol))
        if bad.size:
            i, j = bad[0]
            unit = ("rad", "rad/s", "rad/s²")[nu]
            advice = ("the spline swings past it between points: add points or change "
                      "their velocities" if nu == 0 else "slow it down: later time_from_start")
            raise InvalidGoal(f"the trajectory needs {limits.names[j]} {what} "
                              f"{values[i, j]:.4g} {unit} at t = {ts[i]:.3f} s, beyond its "
                              f"limit {(hi[j] if values[i, j] > hi[j] else lo[j]):.4g} "
                              f"({advice})")


def start_time(header_stamp: float, duration: float, now: float) -> tuple[float, float]:
    """When a goal starts and how late it is, as (start, elapsed) in s on the controller's
    clock: a zero header stamp starts ``now`` (elapsed 0), as joint_trajectory_controller
    reads it; a future stamp starts then (elapsed 0); a past stamp starts now with
    ``elapsed`` = now - stamp (pass it to :func:`build_trajectory`, which drops the points
    already due). Raises :class:`OldHeaderTimestamp` if the stamp plus the goal's last
    ``time_from_start`` (``duration``) is past."""
    if not (math.isfinite(header_stamp) and math.isfinite(now)):
        raise OldHeaderTimestamp(f"header.stamp {header_stamp!r} or now {now!r} not finite")
    if header_stamp == 0.0:
        return now, 0.0
    if header_stamp + duration < now:
        raise OldHeaderTimestamp(f"header.stamp is {now - header_stamp:.3f} s ago and the "
                                 f"trajectory lasts {duration:.3f} s: it would be over")
    if header_stamp > now:
        return header_stamp, 0.0
    return now, now - header_stamp
