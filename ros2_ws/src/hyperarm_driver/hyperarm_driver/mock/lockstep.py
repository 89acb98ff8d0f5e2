"""The mock's lockstep rule (``lockstep_timeout``, simulated time only; no ROS).

While a controller answers each published joint state with a command carrying that
state's stamp, the simulation waits for the answer to the last state before its next step,
at most ``timeout`` s of wall time. A controller is taken as answering once a command
answers any of the recent states; after a timeout the step goes ahead and the simulation
waits again only once an answer comes. Nobody answering, it never waits.

Thread use: the simulation thread calls :meth:`published` and :meth:`wait`; the thread
that receives commands calls :meth:`answered` after the command is applied. Stamps are any
hashable values (the mock uses ``(sec, nanosec)``).
"""
from __future__ import annotations

import collections
import threading
from typing import Hashable

__all__ = ["Lockstep"]


class Lockstep:
    """Lockstep with ``timeout`` s of wall time (> 0) per step at most; ``recent``: how
    many published stamps count as recent."""

    def __init__(self, timeout: float, recent: int = 128) -> None:
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) \
                or not 0.0 < timeout <= 60.0:
            raise ValueError(f"lockstep timeout must be in (0, 60] s, got {timeout!r}")
        self.timeout = float(timeout)
        self.engaged = False            # a controller answers the states: wait for it
        self.timeouts = 0               # waits that ended without the answer
        self._awaited: Hashable | None = None
        self._answered = threading.Event()
        self._recent: collections.deque = collections.deque(maxlen=recent)
        self._lock = threading.Lock()

    def published(self, stamp: Hashable) -> None:
        """Call before publishing the state stamped ``stamp``: it is the one awaited now
        (a late answer to an earlier one arriving from here on does not count for it)."""
        with self._lock:
            self._awaited = stamp
            self._answered.clear()
            self._recent.append(stamp)

    def answered(self, stamp: Hashable) -> None:
        """A command with header stamp ``stamp`` has been applied (or refused)."""
        with self._lock:
            if stamp not in self._recent:
                return                   # not an answer to a state (e.g. a teleop command)
            self.engaged = True
            if stamp == self._awaited:
                self._answered.set()

    def wait(self) -> bool:
        """Before a step: wait for the answer to the last state while engaged. Returns
        False after a timeout (then disengaged until an answer comes), else True."""
        if not self.engaged or self._answered.wait(self.timeout):
            return True
        with self._lock:
            self.timeouts += 1
            self.engaged = False
        return False
