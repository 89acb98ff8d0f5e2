"""Exceptions of the IK family (no ROS). Catch :class:`IKError` for all of them."""
from __future__ import annotations

__all__ = [
    "IKError",
    "InvalidTargetError",
    "InvalidSeedError",
    "InvalidOptionError",
    "UnknownSolverError",
    "FrameError",
    "UnsupportedVariantError",
]


class IKError(ValueError):
    """Root of every error raised by hyperarm_ik's kinematics, solvers and service core."""


class InvalidTargetError(IKError):
    """The target pose is malformed: non-finite numbers, non-unit quaternion, bad shape."""


class InvalidSeedError(IKError):
    """The seed has the wrong length, unknown/missing/duplicate names or non-finite values."""


class InvalidOptionError(IKError):
    """A tolerance, timeout, iteration count or solver option is out of range."""


class UnknownSolverError(IKError):
    """No solver of that name; the message lists the valid names."""


class FrameError(IKError):
    """The target is expressed in a frame the solver does not accept."""


class UnsupportedVariantError(IKError):
    """The solver does not apply to this robot variant (e.g. ``augmented`` needs the rail)."""
