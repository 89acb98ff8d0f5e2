"""Throttling of repeated log messages per reason (no ROS).

rclpy's ``throttle_duration_sec`` throttles per call site: one call site logging several
kinds of rejection would hide a new kind behind the last one. :class:`ReasonThrottle` keeps
one clock per reason instead; the caller logs when :meth:`allow` says so.
"""
from __future__ import annotations

import math
import time

__all__ = ["ReasonThrottle"]


class ReasonThrottle:
    """``allow(reason)`` is True at most once per ``period`` s for each reason; the number
    of messages suppressed since the last allowed one is returned by :meth:`suppressed`."""

    def __init__(self, period: float) -> None:
        if not 0.0 <= period < math.inf:
            raise ValueError(f"throttle period must be >= 0 s, got {period}")
        self.period = period
        self._last: dict[str, float] = {}
        self._skipped: dict[str, int] = {}

    def allow(self, reason: str, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        if now - self._last.get(reason, -math.inf) >= self.period:
            self._last[reason] = now
            return True
        self._skipped[reason] = self._skipped.get(reason, 0) + 1
        return False

    def suppressed(self, reason: str) -> int:
        """Messages of ``reason`` suppressed since the last allowed one (then reset)."""
        return self._skipped.pop(reason, 0)
