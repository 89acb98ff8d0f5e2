"""Exceptions of the force controller's core (no ROS). Catch :class:`ForceError` for all.

:class:`ForceError` derives from :class:`hyperarm_ik.errors.IKError`, the root of every
hyperarm_ik error, so one ``except IKError`` still catches everything the package raises.
"""
from __future__ import annotations

from hyperarm_ik.errors import IKError

__all__ = ["ForceError", "ForceConfigError", "InvalidGoalError", "StateError",
           "CalibrationError"]


class ForceError(IKError):
    """Root of every error raised by ``hyperarm_control.force``."""


class ForceConfigError(ForceError):
    """A controller, estimator or calibration setting is out of range or malformed."""


class InvalidGoalError(ForceError):
    """A hybrid goal is refused: NaN, non-unit quaternion, bad stiffness, unknown frame,
    or a pose far outside the workspace. The message says which."""


class StateError(ForceError):
    """Joint states unusable for a control cycle: wrong length, non-finite values."""


class CalibrationError(ForceError):
    """Calibration data or file is unusable (too few poses, malformed YAML, wrong joints)."""
