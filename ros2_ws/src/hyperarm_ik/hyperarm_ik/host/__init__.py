"""Host-motion compensation and the arm's reaction on its mount (issue 15, no ROS).

- ``compensation``: the host's pose and twist (:class:`HostState`, from the rail joint by
  :class:`RailHost`) and the per-cycle, warm-started, step-limited IK that keeps tool0 at a
  world pose while the host moves (:class:`Compensator`);
- ``reaction``: the wrench the arm exerts on its mount from pinocchio's RNEA
  (:class:`ReactionModel`).
"""
from .compensation import (CompensationConfig, Compensator, CompensationStep, DelayEstimator,
                           HostState, RailHost, Status)
from .errors import (HostConfigError, HostError, HostGoalError, HostStateError,
                     NotStartedError)
from .reaction import ReactionModel

__all__ = ["CompensationConfig", "Compensator", "CompensationStep", "DelayEstimator",
           "HostState", "RailHost",
           "Status", "HostConfigError", "HostError", "HostGoalError", "HostStateError",
           "NotStartedError", "ReactionModel"]
