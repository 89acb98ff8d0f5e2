"""A periodic check's view of its own scheduling (no ROS).

A node's staleness check (no joint states for ``stale_timeout`` s: go passive) must not
take the node's own not running (a loaded machine did not schedule it) for its inputs'
silence: the messages queued meanwhile are read right after. :class:`OwnGap` tells a check
that comes more than ``timeout`` s after the previous one, so that it skips judging once;
the next check judges. Used by the force controller's and the host compensation's
``check_stale``. Times in s on one clock.
"""
from __future__ import annotations

__all__ = ["OwnGap"]


class OwnGap:
    """Gaps longer than ``timeout`` s between successive :meth:`after_gap` calls."""

    def __init__(self, timeout: float) -> None:
        self.timeout = float(timeout)
        self._last: float | None = None

    def after_gap(self, now: float) -> bool:
        """Record a check at ``now``; True when the previous one was more than ``timeout``
        s before (this process did not run meanwhile)."""
        last, self._last = self._last, now
        return last is not None and now - last > self.timeout
