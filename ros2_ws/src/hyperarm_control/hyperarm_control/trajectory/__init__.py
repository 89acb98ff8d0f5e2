"""The joint trajectory core (issue 26): a FollowJointTrajectory goal checked and turned into
splines (:mod:`.goal`), followed cycle by cycle with tolerances and the per-cycle step limit
(:mod:`.follow`), the one-commander rule seen from the controller (:mod:`.handover`),
errors carrying the action's codes (:mod:`.errors`). No ROS."""
from .errors import (SUCCESSFUL, GoalToleranceViolated, InvalidGoal, InvalidJoints,
                     OldHeaderTimestamp, PathToleranceViolated, TrajectoryError)
from .follow import Cycle, Follower, Tolerances, resolve_tolerance
from .handover import CommanderWatch
from .state_check import StateCheck
from .goal import JointLimits, Trajectory, build_trajectory, start_time

__all__ = ["SUCCESSFUL", "GoalToleranceViolated", "InvalidGoal", "InvalidJoints",
           "OldHeaderTimestamp", "PathToleranceViolated", "TrajectoryError", "Cycle",
           "CommanderWatch", "StateCheck",
           "Follower", "Tolerances", "resolve_tolerance", "JointLimits", "Trajectory",
           "build_trajectory", "start_time"]
