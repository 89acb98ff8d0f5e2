"""Exceptions of the Dynamixel bus package (one root, precise subclasses)."""
from __future__ import annotations

__all__ = [
    "DynamixelError",
    "ConfigError",
    "PortError",
    "PortOpenError",
    "PortLostError",
    "CommError",
    "StartupError",
    "CommandError",
    "ProtocolError",
]


class DynamixelError(Exception):
    """Root of every error raised by ``hyperarm_driver.dynamixel``."""


class ConfigError(DynamixelError, ValueError):
    """The per-joint servo configuration is invalid (unknown model, bad limits, ...)."""


class PortError(DynamixelError):
    """The serial port cannot be used."""


class PortOpenError(PortError):
    """The serial port could not be opened (message names the port)."""


class PortLostError(PortError):
    """The serial port went away while in use (USB unplugged, emulator closed)."""


class CommError(DynamixelError):
    """A transaction failed (timeout, corrupt reply) or a servo answered with an error."""


class StartupError(DynamixelError):
    """The start-up check failed: servos missing or of the wrong model.

    ``missing`` lists the joint names that did not answer; ``wrong_model`` maps joint names to
    (expected, found) model names.
    """

    def __init__(self, message: str, missing: list[str] | None = None,
                 wrong_model: dict[str, tuple[str, str]] | None = None) -> None:
        super().__init__(message)
        self.missing = list(missing or [])
        self.wrong_model = dict(wrong_model or {})


class CommandError(DynamixelError, ValueError):
    """A joint command was rejected (unknown joint, NaN/inf, length mismatch).

    ``reason`` names the kind of defect (``length``, ``empty``, ``type``, ``duplicate``,
    ``unknown_joint``, ``non_finite``), so that logs can be throttled per reason.
    """

    def __init__(self, message: str, reason: str = "invalid") -> None:
        super().__init__(message)
        self.reason = reason


class ProtocolError(DynamixelError, ValueError):
    """Bytes that are not a valid Protocol 2.0 packet."""
