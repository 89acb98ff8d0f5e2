"""The task errors: one root, precise subclasses (no ROS)."""
from __future__ import annotations

__all__ = ["TaskError", "UnknownTaskError", "TaskFileError", "StepFailed", "Cancelled"]


class TaskError(Exception):
    """Root of every hyperarm_tasks error."""


class UnknownTaskError(TaskError):
    """No task file of that name in the task directories."""


class TaskFileError(TaskError):
    """A task file is invalid: ``file:line: reason`` (raised at load, before anything moves)."""

    def __init__(self, file: str, line: int | None, reason: str) -> None:
        self.file, self.line, self.reason = file, line, reason
        where = f"{file}:{line}" if line is not None else file
        super().__init__(f"{where}: {reason}")


class StepFailed(TaskError):
    """A step could not do its job. ``kind`` classifies the failure (``ik``, ``grasp``,
    ``grasp_lost``, ``insertion``, ``detection``, ``driver``, ``timeout``, ``joint_fault``,
    ``condition``, ``tracking``)
    so retry rules can match it; the message is the reason shown to the user."""

    def __init__(self, kind: str, message: str) -> None:
        self.kind = kind
        super().__init__(message)


class Cancelled(TaskError):
    """The goal was cancelled (or the node is shutting down) while a step ran."""
