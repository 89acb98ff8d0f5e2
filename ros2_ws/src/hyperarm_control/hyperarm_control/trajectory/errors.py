"""The trajectory core's errors, each with the ``control_msgs/FollowJointTrajectory``
result code a node answers with (the codes are the action's documented constants)."""
from __future__ import annotations

__all__ = ["SUCCESSFUL", "TrajectoryError", "InvalidGoal", "InvalidJoints",
           "OldHeaderTimestamp", "PathToleranceViolated", "GoalToleranceViolated"]

#: FollowJointTrajectory.Result.SUCCESSFUL
SUCCESSFUL = 0


class TrajectoryError(ValueError):
    """Root of the trajectory core's errors; ``code`` is the action's error code and the
    message says what is wrong, naming the joint, point or time."""

    code = -1


class InvalidGoal(TrajectoryError):
    """A goal that cannot be followed: times, sizes, NaN, beyond the limits (INVALID_GOAL)."""

    code = -1


class InvalidJoints(TrajectoryError):
    """joint_names are not exactly the controller's joints (INVALID_JOINTS)."""

    code = -2


class OldHeaderTimestamp(TrajectoryError):
    """The goal's start (header.stamp) plus its duration lies in the past
    (OLD_HEADER_TIMESTAMP)."""

    code = -3


class PathToleranceViolated(TrajectoryError):
    """A joint left its path tolerance while the trajectory ran (PATH_TOLERANCE_VIOLATED)."""

    code = -4


class GoalToleranceViolated(TrajectoryError):
    """The arm was not within the goal tolerance ``goal_time_tolerance`` s after the
    trajectory's end (GOAL_TOLERANCE_VIOLATED)."""

    code = -5
