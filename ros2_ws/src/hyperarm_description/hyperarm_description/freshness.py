"""Freshness of stamped streams (plain Python, no ROS).

Every consumer of a stamped stream (``host_pose``, ``joint_states``, detections, hybrid
goals) decides with one :class:`StampGate` whether a message is new enough to use:

- a message older than the newest one already used from the same source is *out of order*;
- a message older than ``max_age`` s (by the consumer's clock) is *stale*;
- a message stamped more than ``max_future`` s ahead of the consumer's clock is *from the
  future* (a skewed clock: used, it would make every later honest message look old);
- an unstamped message (stamp 0) is used as stamped on arrival only if ``allow_unstamped``.

Rejections are counted per reason (:attr:`StampGate.counts`, for diagnostics) and come
back as a :class:`StampRejection` whose ``reason`` names the kind and whose ``text`` names
the stream, the source, the age and the limit, for a log line throttled per reason.
Times are seconds on the consumer's clock (ROS time: sim time where it runs).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Hashable

__all__ = ["StampGate", "StampRejection", "REJECT_REASONS", "stamp_seconds"]

REJECT_REASONS = ("out_of_order", "stale", "future", "unstamped")


def stamp_seconds(stamp) -> float:
    """A ``builtin_interfaces/Time``-like object (``sec``, ``nanosec``) -> seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


@dataclass(frozen=True)
class StampRejection:
    """Why a message was not used: ``reason`` is one of :data:`REJECT_REASONS` (the key
    of the count and of the log throttle), ``text`` a sentence for the log."""

    reason: str
    text: str


class StampGate:
    """Accepts stamped messages in order and fresh; see the module docstring.

    ``stream``: the stream's name, for messages. ``max_age``: s, > 0. ``max_future``: s,
    >= 0. Thread-safe (callbacks of a multi-threaded executor may share it)."""

    def __init__(self, stream: str, max_age: float, max_future: float = 0.5,
                 allow_unstamped: bool = False) -> None:
        if not (math.isfinite(max_age) and max_age > 0.0):
            raise ValueError(f"{stream}: max_age must be a finite number > 0 s, got {max_age}")
        if not (math.isfinite(max_future) and max_future >= 0.0):
            raise ValueError(f"{stream}: max_future must be finite and >= 0 s, got {max_future}")
        self.stream = stream
        self.max_age = float(max_age)
        self.max_future = float(max_future)
        self.allow_unstamped = bool(allow_unstamped)
        self.counts: dict[str, int] = {r: 0 for r in REJECT_REASONS}
        self.accepted = 0
        self._newest: dict[Hashable, float] = {}
        self._lock = threading.Lock()

    def newest(self, source: Hashable = None) -> float | None:
        """The stamp (s) of the newest message used from ``source``, or None."""
        with self._lock:
            return self._newest.get(source)

    def reset(self, source: Hashable = None) -> None:
        """Forget ``source``'s newest stamp (e.g. after the clock jumped back)."""
        with self._lock:
            self._newest.pop(source, None)

    def check(self, stamp: float, now: float, source: Hashable = None) -> StampRejection | None:
        """None if the message stamped ``stamp`` (s; 0 = unstamped) may be used at ``now``
        (s) and marks it as the newest of ``source``; else the rejection (counted)."""
        with self._lock:
            where = "" if source is None else f" from {source}"
            if stamp == 0.0:
                if not self.allow_unstamped:
                    return self._reject("unstamped", f"{self.stream}{where} ignored: the "
                                        "message has no header.stamp (0)")
                stamp = now
            if not math.isfinite(stamp):
                return self._reject("stale", f"{self.stream}{where} ignored: stamp {stamp}")
            age = now - stamp
            if age > self.max_age:
                return self._reject("stale", f"{self.stream}{where} ignored: stamped "
                                    f"{age:.3f} s ago, older than max_age {self.max_age:g} s")
            if -age > self.max_future:
                return self._reject("future", f"{self.stream}{where} ignored: stamped "
                                    f"{-age:.3f} s in the future (clock skew?), more than "
                                    f"{self.max_future:g} s")
            newest = self._newest.get(source)
            if newest is not None and stamp < newest:
                return self._reject("out_of_order", f"{self.stream}{where} ignored: stamped "
                                    f"{newest - stamp:.3f} s before the newest one used")
            self._newest[source] = stamp
            self.accepted += 1
            return None

    def _reject(self, reason: str, text: str) -> StampRejection:
        self.counts[reason] += 1
        return StampRejection(reason, text)
