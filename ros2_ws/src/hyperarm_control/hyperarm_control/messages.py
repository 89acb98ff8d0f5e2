"""Message conversions of the arm controller: trajectory_msgs and control_msgs to and from the
trajectory core's arrays (SI units: s, rad, m). No node, no rclpy; only message classes."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from .trajectory import Cycle, InvalidGoal, Tolerances

__all__ = ["seconds", "TrajectoryArgs", "trajectory_args", "goal_tolerances", "point",
           "feedback"]


def seconds(stamp) -> float:
    """A builtin_interfaces Time or Duration in s."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


@dataclass(frozen=True)
class TrajectoryArgs:
    """What :func:`~hyperarm_control.trajectory.build_trajectory` takes from a
    JointTrajectory, with its header stamp (s; 0 = start now)."""

    joint_names: list[str]
    times: list[float]
    positions: list[list[float]]
    velocities: list[list[float]]
    accelerations: list[list[float]]
    stamp: float

    @property
    def duration(self) -> float:
        return max(self.times) if self.times else 0.0


def trajectory_args(msg: JointTrajectory) -> TrajectoryArgs:
    points = msg.points
    return TrajectoryArgs(list(msg.joint_names), [seconds(p.time_from_start) for p in points],
                          [list(p.positions) for p in points],
                          [list(p.velocities) for p in points],
                          [list(p.accelerations) for p in points], seconds(msg.header.stamp))


def goal_tolerances(goal, names: Sequence[str], defaults: Tolerances) -> Tolerances:
    """A FollowJointTrajectory goal's tolerances over the controller's ``defaults``.
    Multi-DOF parts are refused (this arm has none); a JointTolerance acceleration other
    than 0 is refused, as the drivers measure no acceleration to check it against."""
    if goal.multi_dof_trajectory.points or goal.multi_dof_trajectory.joint_names:
        raise InvalidGoal("multi_dof_trajectory: this controller has no multi-DOF joints")
    if goal.component_path_tolerance or goal.component_goal_tolerance:
        raise InvalidGoal("component_*_tolerance: this controller has no multi-DOF joints")
    path, target = {}, {}
    for given, out, what in ((goal.path_tolerance, path, "path_tolerance"),
                             (goal.goal_tolerance, target, "goal_tolerance")):
        for tol in given:
            if tol.acceleration not in (0.0, -1.0):
                raise InvalidGoal(f"{what} of {tol.name}: acceleration tolerances cannot be "
                                  "checked (no measured acceleration); use 0 or -1")
            if tol.name in out:
                raise InvalidGoal(f"{what}: {tol.name} given twice")
            out[tol.name] = (tol.position, tol.velocity)
    return Tolerances.resolve(names, defaults, path, target,
                              seconds(goal.goal_time_tolerance))


def point(positions: np.ndarray, velocities: np.ndarray | None = None,
          accelerations: np.ndarray | None = None, t: float = 0.0) -> JointTrajectoryPoint:
    pt = JointTrajectoryPoint(positions=[float(x) for x in positions])
    if velocities is not None:
        pt.velocities = [float(x) for x in velocities]
    if accelerations is not None:
        pt.accelerations = [float(x) for x in accelerations]
    t = max(0.0, float(t))
    pt.time_from_start.sec = int(t)
    pt.time_from_start.nanosec = int((t - int(t)) * 1e9)
    return pt


def feedback(feedback_cls, cycle: Cycle, names: Sequence[str], stamp):
    """FollowJointTrajectory feedback from one control cycle: desired, actual (measured
    position) and error (desired - actual), at ``cycle.time`` from the goal's start."""
    fb = feedback_cls()
    fb.header.stamp = stamp
    fb.joint_names = list(names)
    fb.desired = point(cycle.desired, cycle.desired_velocity, cycle.desired_acceleration,
                       cycle.time)
    fb.actual = point(cycle.actual, t=cycle.time)
    fb.error = point(cycle.error, t=cycle.time)
    return fb
