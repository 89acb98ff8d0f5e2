"""The one-commander rule, seen from a controller (issue 26; docs/architecture.md, "Who
commands the arm"). No ROS.

Several nodes may command the arm through ``joint_command`` (hybrid_force,
host_compensation, the task node, arm_controller), one at a time. A controller sees every
``joint_command`` on the topic, its own included (a ROS 2 subscription receives the node's
own publications). :class:`CommanderWatch` tells the two apart: a message naming any of the
controller's joints that is not one of the controller's own recent commands (same joints,
same positions, exactly: the values come back bit for bit) comes from another commander.

The controller then takes part in the rule:

- a new goal is refused while another commander was heard within ``quiet`` s (it is active,
  or has just sent its hold);
- a goal that runs stops at once, without a command of its own, when another commander is
  heard (two streams would fight; the other one is holding or moving the arm).

Times are seconds on one clock (the node's).
"""
from __future__ import annotations

import math
from collections import deque
from typing import Sequence

__all__ = ["CommanderWatch"]


class CommanderWatch:
    """See the module. ``joints``: the controller's joint names; ``quiet`` (s, >= 0): how
    long after another commander's last message a goal is refused (0: never); ``memory``:
    how many of its own commands are remembered (commands in flight)."""

    def __init__(self, joints: Sequence[str], quiet: float, memory: int = 64) -> None:
        if not (math.isfinite(quiet) and quiet >= 0.0):
            raise ValueError(f"quiet must be a finite time >= 0 s, got {quiet!r}")
        if memory < 1:
            raise ValueError(f"memory must be >= 1, got {memory!r}")
        self.joints = tuple(joints)
        self._set = frozenset(self.joints)
        self.quiet = float(quiet)
        self._sent: deque[tuple[float, ...]] = deque(maxlen=memory)
        self.last_other: float = -math.inf      # when another commander was last heard
        self.other_joints: tuple[str, ...] = ()
        self.heard = 0                          # messages from other commanders

    def sent(self, positions: Sequence[float]) -> None:
        """Note a command this controller publishes (its joints, in order)."""
        self._sent.append(tuple(float(x) for x in positions))

    def observe(self, names: Sequence[str], positions: Sequence[float], now: float) -> bool:
        """A ``joint_command`` heard at ``now``: True if it comes from another commander
        (it names one of the controller's joints and is not one of its own commands)."""
        if not self._set.intersection(names):
            return False                        # another joint set (the gripper): not ours
        if tuple(names) == self.joints and len(positions) == len(self.joints):
            key = tuple(float(x) for x in positions)
            if key in self._sent:
                return False
        self.last_other = float(now)
        self.other_joints = tuple(n for n in names if n in self._set)
        self.heard += 1
        return True

    def busy(self, now: float) -> str | None:
        """Why a new goal must wait, or None: another commander was heard less than
        ``quiet`` s ago."""
        age = float(now) - self.last_other
        if self.quiet <= 0.0 or not age < self.quiet:
            return None
        return (f"another node commands {', '.join(self.other_joints)} on joint_command "
                f"(heard {age:.3f} s ago): one commander at a time; stop it (e.g. "
                f"hybrid_force/enable false, cancel the task) and send the goal "
                f"{self.quiet:g} s after its last command")
