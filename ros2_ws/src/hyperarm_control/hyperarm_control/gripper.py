"""The gripper command core (issue 26): a ``control_msgs/GripperCommand`` goal checked and
judged from the measured state, as ros2_controllers' ``gripper_action_controller`` does
(no ROS).

A goal is the gripper joint's position (rad, the joint's own units: 0 = closed, the upper
limit = fully open, as MoveIt sends it) and ``max_effort`` (N·m, the servo's current limit
in current-based position; 0 = the controller's ``max_effort`` parameter, and if that is 0
too, the driver's default limit, the description's ``grip_effort``). :func:`check_goal`
refuses NaN/inf, a negative effort and a position outside the joint's limits
(:class:`InvalidGripperGoal`); an effort above the servo's stall torque is clamped to it,
as the drivers clamp it.

:class:`GripperJudge` judges each measured state (position, velocity, effort, stamp):

- **reached**: ``|position - goal| <= goal_tolerance`` -> succeeded, ``reached_goal``;
- **stalled**: the measured velocity at or below ``stall_velocity_threshold`` for
  ``stall_timeout`` s without reaching the goal, *and* the measured effort pushing towards
  the goal at ``stall_effort_fraction`` of the limit or more (GripperCommand: "exerting max
  effort and not moving"; the drivers report the servo's torque: the mock's grip torque,
  the Dynamixel's present current, both at the limit on an object). With ``allow_stalling``
  the goal then succeeds with ``stalled`` true (a grasp), else it aborts, as
  gripper_action_controller does. Not moving, short of the goal, without that effort is not
  a stall: it aborts, saying so (torque off, a servo error);
- **stale state**: a state older than ``max_state_age`` s aborts (the drivers keep the last
  goal);
- :meth:`GripperJudge.cancel` ends the goal (canceled) and gives the hold: the measured
  position. :meth:`GripperJudge.start` with a new goal preempts the running one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["GripperError", "InvalidGripperGoal", "GripperLimits", "GripperParams",
           "GripperGoal", "GripperStatus", "GripperJudge", "check_goal"]


class GripperError(ValueError):
    """Root of the gripper core's errors; the message says what is wrong."""


class InvalidGripperGoal(GripperError):
    """A GripperCommand goal that cannot be run: NaN/inf, a negative effort, a position
    outside the gripper joint's limits."""


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise GripperError(f"{name} must be finite, got {value!r}")
    return value


@dataclass(frozen=True)
class GripperLimits:
    """The gripper joint: ``lower``/``upper`` position limits (rad), ``stall_effort`` (N·m,
    the servo's largest torque) and ``default_effort`` (N·m, the drivers' limit of a
    position command without an effort: the description's ``grip_effort``)."""

    name: str
    lower: float
    upper: float
    stall_effort: float
    default_effort: float

    def __post_init__(self) -> None:
        for key in ("lower", "upper", "stall_effort", "default_effort"):
            _finite(key, getattr(self, key))
        if not self.lower < self.upper:
            raise GripperError(f"{self.name}: lower limit {self.lower} must be < upper "
                               f"limit {self.upper}")
        if not (self.stall_effort > 0 and self.default_effort > 0):
            raise GripperError(f"{self.name}: stall_effort and default_effort must be > 0")

    @classmethod
    def from_description(cls, desc) -> "GripperLimits":
        g = desc.gripper
        return cls(g.name, float(g.lower), float(g.upper), float(g.effort),
                   float(min(g.grip_effort, g.effort)))


@dataclass(frozen=True)
class GripperParams:
    """gripper_action_controller's parameters (rad, rad/s, s, N·m) plus ours:
    ``stall_effort_fraction`` (0..1; 0 = a stall is judged on the velocity alone, as
    gripper_action_controller does) and ``max_state_age`` (s)."""

    goal_tolerance: float = 0.01
    stall_velocity_threshold: float = 0.05
    stall_timeout: float = 1.0
    allow_stalling: bool = True
    max_effort: float = 0.0
    stall_effort_fraction: float = 0.8
    max_state_age: float = 0.25

    def __post_init__(self) -> None:
        for key in ("goal_tolerance", "stall_velocity_threshold", "stall_timeout",
                    "max_effort", "stall_effort_fraction", "max_state_age"):
            if _finite(key, getattr(self, key)) < 0:
                raise GripperError(f"{key} must be >= 0, got {getattr(self, key)!r}")
        if self.stall_effort_fraction > 1.0:
            raise GripperError(f"stall_effort_fraction must be within 0..1, got "
                               f"{self.stall_effort_fraction!r}")
        if self.max_state_age <= 0 or self.stall_timeout <= 0:
            raise GripperError("max_state_age and stall_timeout must be > 0 s")


@dataclass(frozen=True)
class GripperGoal:
    """A checked goal: ``position`` (rad), ``effort_command`` (N·m for ``joint_command``'s
    effort: 0 = the driver's default limit), ``limit`` (N·m, the limit the servo then
    enforces, for the stall judgement) and ``clamped`` (the request was above the stall
    torque)."""

    position: float
    effort_command: float
    limit: float
    clamped: bool = False


def check_goal(position: float, max_effort: float, limits: GripperLimits,
               params: GripperParams) -> GripperGoal:
    """A GripperCommand's ``position`` (rad) and ``max_effort`` (N·m) -> :class:`GripperGoal`;
    raises :class:`InvalidGripperGoal` naming the problem."""
    position, max_effort = float(position), float(max_effort)
    if not math.isfinite(position):
        raise InvalidGripperGoal(f"position {position!r} is not a finite number (rad)")
    if not math.isfinite(max_effort):
        raise InvalidGripperGoal(f"max_effort {max_effort!r} is not a finite number (N·m)")
    if max_effort < 0:
        raise InvalidGripperGoal(f"max_effort {max_effort:g} N·m is negative (>= 0; 0 = the "
                                 f"default limit)")
    eps = 1e-9
    if not limits.lower - eps <= position <= limits.upper + eps:
        raise InvalidGripperGoal(
            f"position {position:.4g} rad outside {limits.name}'s limits [{limits.lower:g}, "
            f"{limits.upper:.4g}] rad ({limits.lower:g} = closed, {limits.upper:.4g} = fully "
            f"open)")
    position = min(max(position, limits.lower), limits.upper)
    asked = max_effort if max_effort > 0 else params.max_effort
    if asked <= 0:
        return GripperGoal(position, 0.0, limits.default_effort)
    limit = min(asked, limits.stall_effort)
    return GripperGoal(position, limit, limit, asked > limits.stall_effort)


@dataclass(frozen=True)
class GripperStatus:
    """One judgement: ``status`` ``idle``, ``running``, ``succeeded``, ``aborted`` or
    ``canceled``; the measured ``position`` (rad) and ``effort`` (N·m; NaN if the driver
    reports none), ``stalled``, ``reached_goal`` and ``reason`` (a sentence when it ended)."""

    status: str
    position: float
    effort: float
    stalled: bool = False
    reached_goal: bool = False
    reason: str = ""

    @property
    def done(self) -> bool:
        return self.status in ("succeeded", "aborted", "canceled")


class GripperJudge:
    """Judges one goal at a time from the measured state (see the module docstring).
    Times are seconds on one clock (the node's); ``stamp`` is the state's measurement time."""

    def __init__(self, limits: GripperLimits, params: GripperParams) -> None:
        if not isinstance(limits, GripperLimits) or not isinstance(params, GripperParams):
            raise GripperError("GripperJudge(limits: GripperLimits, params: GripperParams)")
        self.limits, self.params = limits, params
        self.goal: GripperGoal | None = None
        self._still_since = 0.0

    @property
    def running(self) -> bool:
        return self.goal is not None

    def start(self, goal: GripperGoal, now: float) -> bool:
        """Run ``goal`` from ``now``; returns True if it preempted a running goal."""
        if not isinstance(goal, GripperGoal):
            raise GripperError("start() takes a GripperGoal (from check_goal)")
        preempted = self.goal is not None
        self.goal = goal
        self._still_since = _finite("now", now)
        return preempted

    def cancel(self, position: float, effort: float = math.nan) -> GripperStatus:
        """End the running goal: canceled, holding at the measured ``position``."""
        self.goal = None
        return GripperStatus("canceled", float(position), float(effort),
                             reason=f"cancelled: holding at {float(position):.4f} rad")

    def step(self, now: float, position: float, velocity: float, effort: float,
             stamp: float) -> GripperStatus:
        """Judge the state measured at ``stamp``: position (rad), velocity (rad/s), effort
        (N·m, NaN = not reported). Ends the goal (``goal`` None) when it returns a final
        status."""
        goal, p = self.goal, self.params
        if goal is None:
            return GripperStatus("idle", float(position), float(effort))
        age = float(now) - float(stamp)
        if not (math.isfinite(age) and math.isfinite(position) and math.isfinite(velocity)):
            return self._end("aborted", position, effort, reason=(
                f"{self.limits.name}: non-finite state (position {position!r}, velocity "
                f"{velocity!r}, stamp {stamp!r}); the gripper keeps its last goal"))
        if age > p.max_state_age:
            return self._end("aborted", position, effort, reason=(
                f"{self.limits.name}: joint_states {age:.3f} s old, older than max_state_age "
                f"{p.max_state_age:g} s; the gripper keeps its last goal"))
        error = goal.position - position
        if abs(error) <= p.goal_tolerance:
            return self._end("succeeded", position, effort, reached=True, reason=(
                f"reached {position:.4f} rad (goal {goal.position:.4f})"))
        if abs(velocity) > p.stall_velocity_threshold:
            self._still_since = float(now)
        elif now - self._still_since >= p.stall_timeout:
            known = math.isfinite(effort)
            pushing = (not known or p.stall_effort_fraction == 0.0 or
                       (abs(effort) >= p.stall_effort_fraction * goal.limit
                        and effort * error > 0))
            where = (f"at {position:.4f} rad, {abs(error):.4f} rad short of the goal "
                     f"{goal.position:.4f}")
            if pushing:
                force = (f"effort {effort:.3f} N·m, limit {goal.limit:.3g}" if known
                         else "effort not reported")
                if p.allow_stalling:
                    return self._end("succeeded", position, effort, stalled=True, reason=(
                        f"stalled {where} ({force}): holding"))
                return self._end("aborted", position, effort, stalled=True, reason=(
                    f"stalled {where} ({force}) and allow_stalling is false"))
            return self._end("aborted", position, effort, reason=(
                f"stopped {where} for {p.stall_timeout:g} s with effort {effort:.3f} N·m, "
                f"below {p.stall_effort_fraction:g} x the limit {goal.limit:.3g} N·m towards "
                f"the goal: not held by an object (torque off? a servo error?)"))
        return GripperStatus("running", float(position), float(effort))

    def _end(self, status: str, position: float, effort: float, *, stalled: bool = False,
             reached: bool = False, reason: str = "") -> GripperStatus:
        self.goal = None
        return GripperStatus(status, float(position), float(effort), stalled, reached, reason)
