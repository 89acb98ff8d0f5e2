"""Host-motion compensation and the arm's reaction on its mount (issue 15, no ROS).

- ``compensation``: the host's pose and twist (:class:`HostState`, from the rail joint by
  :class:`RailHost`) and the per-cycle, warm-started, step-limited IK that keeps tool0 at a
  world pose while the host moves (:class:`Compensator`);
- ``loop``: the node's per-message sequencing (enable, horizon, silence) on top of it
  (:class:`CompensationLoop`);
- ``reaction``: the wrench the arm exerts on its mount from pinocchio's RNEA
  (:class:`ReactionModel`; the estimated contact wrench it adds: :class:`LatestWrench`);
- ``redundancy``: IK that uses the three free joints to keep the centre of mass over the
  mount, lowering the base moment (:class:`ReactionMinimizer`).
"""
from .compensation import (MOUNT_POSE_CUTOFF, MOUNT_TWIST_CUTOFF, CompensationConfig, Compensator, CompensationStep, DelayEstimator,
                           HostPoseTracker, HostState, RailHost, Status)
from .errors import (HostConfigError, HostError, HostGoalError, HostStateError,
                     NotStartedError)
from .loop import CompensationLoop
from .reaction import (AccelerationEstimator, HostAccelerationEstimator, LatestWrench,
                       ReactionModel)
from .redundancy import OBJECTIVES, ReactionMinimizer, RedundancyConfig

__all__ = ["MOUNT_POSE_CUTOFF", "MOUNT_TWIST_CUTOFF", "CompensationConfig", "Compensator", "CompensationStep", "DelayEstimator",
           "HostState", "HostPoseTracker", "RailHost", "AccelerationEstimator",
           "ReactionMinimizer", "RedundancyConfig", "OBJECTIVES", "CompensationLoop",
           "Status", "HostConfigError", "HostError", "HostGoalError", "HostStateError",
           "NotStartedError", "ReactionModel", "LatestWrench", "HostAccelerationEstimator"]
