"""Merging joint states by name (plain Python, no ROS).

Every driver publishes only the joints it owns on ``joint_states``; consumers keep the
newest value of each joint and read vectors in the order they need.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

__all__ = ["JointStateError", "JointStateCache", "check_command"]


class JointStateError(ValueError):
    """A joint state or command is malformed, or a needed joint has not been seen."""


@dataclass
class JointStateCache:
    """Newest position/velocity/effort (rad or m, rad/s or m/s, N·m or N) of each joint."""

    position: dict[str, float] = field(default_factory=dict)
    velocity: dict[str, float] = field(default_factory=dict)
    effort: dict[str, float] = field(default_factory=dict)
    stamp: dict[str, float] = field(default_factory=dict)

    def update(self, names: Sequence[str], position: Sequence[float] = (),
               velocity: Sequence[float] = (), effort: Sequence[float] = (),
               stamp: float = 0.0) -> None:
        """Merge one message's worth of joints. Arrays may be empty, else len(names)."""
        n = len(names)
        for label, arr in (("position", position), ("velocity", velocity), ("effort", effort)):
            if len(arr) not in (0, n):
                raise JointStateError(f"{label} has {len(arr)} values for {n} names")
        for i, name in enumerate(names):
            if len(position):
                self.position[name] = float(position[i])
            if len(velocity):
                self.velocity[name] = float(velocity[i])
            if len(effort):
                self.effort[name] = float(effort[i])
            self.stamp[name] = stamp

    def has(self, names: Iterable[str]) -> bool:
        return all(n in self.position for n in names)

    def positions(self, names: Sequence[str]) -> np.ndarray:
        """Positions in the order of ``names``; raises naming any joint not seen yet."""
        missing = [n for n in names if n not in self.position]
        if missing:
            raise JointStateError(f"no joint_states received yet for {', '.join(missing)}")
        return np.array([self.position[n] for n in names])


def check_command(names: Sequence[str], values: Sequence[float], known: Iterable[str],
                  label: str = "position") -> dict[str, float]:
    """Validate a by-name command: lengths match, names known and unique, values finite.

    Returns {name: value}. Raises :class:`JointStateError` with a message naming the
    problem (the caller logs it and drops the command: nothing partial is applied).
    """
    known = set(known)
    if len(values) != len(names):
        raise JointStateError(f"{label}: {len(values)} values for {len(names)} joint names")
    if len(set(names)) != len(names):
        raise JointStateError(f"duplicate joint names in command: {list(names)}")
    unknown = [n for n in names if n not in known]
    if unknown:
        raise JointStateError(f"unknown joint(s) {unknown}; known: {sorted(known)}")
    bad = [n for n, v in zip(names, values) if not math.isfinite(float(v))]
    if bad:
        raise JointStateError(f"non-finite {label} for {bad}")
    return {n: float(v) for n, v in zip(names, values)}


def velocity_problem(names: Sequence[str], velocity: Sequence[float]) -> str | None:
    """What is wrong with a command's ``velocity`` array, or None. No driver commands
    velocities, but a message is judged whole: a ``velocity`` that is not empty must have one
    finite value per name, else the message is malformed and rejected like any other."""
    if len(velocity) == 0:
        return None
    if len(velocity) != len(names):
        return f"velocity: {len(velocity)} values for {len(names)} joint names"
    bad = [n for n, v in zip(names, velocity) if not math.isfinite(float(v))]
    return f"non-finite velocity for {bad}" if bad else None
