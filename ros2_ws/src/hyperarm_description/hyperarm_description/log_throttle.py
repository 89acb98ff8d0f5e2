"""Throttling of repeated log messages per reason (no ROS).

rclpy's ``throttle_duration_sec`` throttles per call site: one call site logging several
kinds of rejection would hide a new kind behind the last one. :class:`ReasonThrottle` keeps
one clock per reason instead; the caller logs when :meth:`allow` says so.
"""
from __future__ import annotations

import math
import re
import threading
import time

__all__ = ["ReasonThrottle", "reason_key"]

_NUMBER = re.compile(r"[-+]?\d+(\.\d*)?([eE][-+]?\d+)?")


def reason_key(text: str) -> str:
    """``text`` with its numbers replaced by ``#``: messages that differ only in their
    figures ("error 0.012 m" / "error 0.013 m") are one reason."""
    return _NUMBER.sub("#", text)


class ReasonThrottle:
    """``allow(reason)`` is True at most once per ``period`` s for each reason; the number
    of messages suppressed since the last allowed one is returned by :meth:`suppressed`."""

    def __init__(self, period: float) -> None:
        if not 0.0 <= period < math.inf:
            raise ValueError(f"throttle period must be >= 0 s, got {period}")
        self.period = period
        self._last: dict[str, float] = {}
        self._skipped: dict[str, int] = {}
        self._lock = threading.Lock()  # callbacks of a multi-threaded executor share it

    def allow(self, reason: str, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        with self._lock:
            if now - self._last.get(reason, -math.inf) >= self.period:
                self._last[reason] = now
                return True
            self._skipped[reason] = self._skipped.get(reason, 0) + 1
            return False

    def suppressed(self, reason: str) -> int:
        """Messages of ``reason`` suppressed since the last allowed one (then reset)."""
        with self._lock:
            return self._skipped.pop(reason, 0)

    def message(self, text: str, reason: str | None = None) -> str | None:
        """``text`` to log now, noting how many messages of its reason (default:
        :func:`reason_key` of ``text``) were suppressed since, or None to stay quiet. The
        caller logs it itself, ``if (m := throttle.message(t)): logger.warn(m)``: rclpy ties
        a severity to the call site, so the logging call must stay in the caller."""
        key = reason_key(text) if reason is None else reason
        if not self.allow(key):
            return None
        skipped = self.suppressed(key)
        return text + (f" ({skipped} more like this suppressed)" if skipped else "")
