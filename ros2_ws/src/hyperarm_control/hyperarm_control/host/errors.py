"""Exceptions of the host-motion core (no ROS). Catch :class:`HostError` for all.

:class:`HostError` derives from :class:`hyperarm_ik.errors.IKError`, the root of every
hyperarm_ik error, so one ``except IKError`` still catches everything the package raises.
"""
from __future__ import annotations

from hyperarm_ik.errors import IKError

__all__ = ["HostError", "HostConfigError", "HostStateError", "HostGoalError",
           "NotStartedError"]


class HostError(IKError):
    """Root of every error raised by ``hyperarm_control.host``."""


class HostConfigError(HostError):
    """A compensation or reaction setting is out of range, or the model does not fit."""


class HostStateError(HostError):
    """A host pose/twist or a joint state is malformed: wrong shape, non-finite, not a
    proper rotation."""


class HostGoalError(HostError):
    """A world-frame tool goal is malformed (shape, non-finite, not a rotation)."""


class NotStartedError(HostError):
    """A compensation step or goal was asked for before :meth:`Compensator.start`."""
