"""Deciding whether a one-shot command of the `hyperarm` CLI was taken (plain Python, no ROS).

The CLI publishes a ``joint_command`` once and must not say "done" on faith: it watches the
owning drivers' ``joint_states`` until every named joint has either reached its goal or moved
towards it by a clear step, and it watches the drivers' log (``/rosout``) for a refusal. A
``joint_states`` table is complete only when every joint asked for has been heard.

Units: revolute joints rad, the rail (``contract.RAIL_JOINT``) m.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

from hyperarm_description import contract

__all__ = ["GoalWatch", "REACHED", "STEP", "is_refusal", "missing_joints"]

# A joint is at its goal within REACHED (rad: ~3 ticks of a 4096-tick Dynamixel; rail: m),
# and a joint that came STEP closer to its goal than where it started has taken the goal.
REACHED = {"revolute": 0.005, "rail": 0.0005}
STEP = {"revolute": 0.01, "rail": 0.001}

# Words with which the drivers log a joint_command they did not apply (dynamixel_driver:
# "joint_command rejected" / "... dropped: torque is off"; pmac_rail_driver and the mock:
# "rail setpoint rejected, nothing sent"; a refused service or a tripped watchdog: "refused").
_REFUSAL_SUBJECTS = ("joint_command", "setpoint")
_REFUSAL_VERBS = ("rejected", "dropped", "refused", "refusing", "tripped")


def _kind(name: str) -> str:
    return "rail" if name == contract.RAIL_JOINT else "revolute"


@dataclass
class GoalWatch:
    """Which joints of a command have been seen taking their goal.

    ``targets``: joint -> goal (rad; rail m). ``start``: joint -> position when the command
    was sent (the newest joint_states before it). A joint has taken its goal once a later
    position is within ``REACHED`` of the goal, or ``STEP`` closer to it than ``start`` was.
    """

    targets: Mapping[str, float]
    start: Mapping[str, float]
    taken: dict[str, float] = field(default_factory=dict)   # joint -> position that showed it

    def __post_init__(self) -> None:
        unknown = set(self.targets) - set(self.start)
        if unknown:
            raise ValueError(f"no start position for {sorted(unknown)}")

    def update(self, positions: Mapping[str, float]) -> None:
        """Feed one joint_states message (joint -> position); NaN positions are ignored."""
        for name, goal in self.targets.items():
            p = positions.get(name)
            if name in self.taken or p is None or not math.isfinite(p):
                continue
            kind = _kind(name)
            before = abs(self.start[name] - goal)
            now = abs(p - goal)
            if now <= REACHED[kind] or before - now >= STEP[kind]:
                self.taken[name] = p

    def pending(self) -> list[str]:
        """Joints not yet seen taking their goal, in command order."""
        return [n for n in self.targets if n not in self.taken]

    def done(self) -> bool:
        return not self.pending()


def is_refusal(text: str) -> bool:
    """True if a driver's log line says it did not apply a joint_command (or setpoint)."""
    low = text.lower()
    return any(s in low for s in _REFUSAL_SUBJECTS) and any(v in low for v in _REFUSAL_VERBS)


def missing_joints(required: Iterable[str], seen: Iterable[str]) -> list[str]:
    """The joints of ``required`` (in order) not among ``seen``."""
    have = set(seen)
    return [n for n in required if n not in have]
