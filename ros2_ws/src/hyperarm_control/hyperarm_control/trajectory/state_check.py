"""Is a measured joint state believable? Per joint, before a controller uses it (no ROS).

A controller that holds the arm "where it is measured" moves the arm to wherever a state
says it is. One wrong ``joint_states`` message (another publisher, a replayed bag, a
driver bug) must therefore not be used. :class:`StateCheck` refuses, per joint of the
controller:

- **non-finite** positions or velocities;
- **out of order**: stamped before the newest state used for that joint (whatever other
  joints the message names: a message naming a subset is still compared joint by joint);
- **implausible jumps**: a joint further from its last used position than its velocity
  limit allows over the time between the two stamps, x ``speed_factor``, plus ``slack``
  (rad or m: noise, quantization). A servo cannot move faster than its limit; a state
  that says so is not the arm.

After a refusal the last used state stays; if only refused states come, the controller's
own age check (stale states) stops it, holding its last command. Units: rad (m for the
rail), s.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

__all__ = ["StateCheck"]


class StateCheck:
    """See the module. ``joints``: the controller's joint names; ``velocity``: their
    limits (rad/s, m/s), same order."""

    def __init__(self, joints: Sequence[str], velocity: Sequence[float],
                 speed_factor: float = 2.0, slack: float = 0.02) -> None:
        v = np.asarray(velocity, dtype=float).reshape(-1)
        if len(joints) != len(v) or not np.all(v > 0) or not np.all(np.isfinite(v)):
            raise ValueError("StateCheck: one finite velocity limit > 0 per joint")
        if not (speed_factor >= 1.0 and math.isfinite(speed_factor)):
            raise ValueError(f"speed_factor must be >= 1, got {speed_factor!r}")
        if not (slack >= 0.0 and math.isfinite(slack)):
            raise ValueError(f"slack must be >= 0, got {slack!r}")
        self.index = {n: i for i, n in enumerate(joints)}
        self.velocity = v
        self.speed_factor = float(speed_factor)
        self.slack = float(slack)
        n = len(v)
        self._stamp = np.full(n, -math.inf)
        self._q = np.full(n, math.nan)

    def check(self, names: Sequence[str], positions: Sequence[float],
              velocities: Sequence[float], stamp: float) -> str | None:
        """None if the state (stamped ``stamp`` s) may be used, and it becomes the last
        used state of its joints; else why not (a sentence naming the joint)."""
        mine = [(k, self.index[n]) for k, n in enumerate(names) if n in self.index]
        if not mine:
            return None
        for k, i in mine:
            name = names[k]
            q = positions[k] if k < len(positions) else math.nan
            v = velocities[k] if k < len(velocities) else 0.0
            if not (math.isfinite(q) and math.isfinite(v)):
                return f"{name}: non-finite position {q!r} or velocity {v!r}"
            if stamp < self._stamp[i]:
                return (f"{name}: stamped {self._stamp[i] - stamp:.3f} s before the newest "
                        "state used for it")
            if math.isfinite(self._q[i]):
                dt = stamp - self._stamp[i]
                allowed = self.velocity[i] * self.speed_factor * dt + self.slack
                if abs(q - self._q[i]) > allowed:
                    return (f"{name}: {q:.4f} is {abs(q - self._q[i]):.4f} from its last "
                            f"state {dt:.3f} s before, more than its velocity limit "
                            f"allows ({allowed:.4f})")
        for k, i in mine:
            self._stamp[i] = stamp
            self._q[i] = positions[k]
        return None
