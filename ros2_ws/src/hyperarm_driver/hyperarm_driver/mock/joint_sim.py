"""Simulated position-controlled joints (no ROS). Units: rad (rail m), s.

Each joint moves toward its goal at no more than its velocity limit. Goals are clamped to
the joint limits before they are stored, so nothing outside the limits is ever tracked.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from hyperarm_description.joints import check_command
from hyperarm_description.model import RobotDescription

__all__ = ["JointSim", "CommandReport"]


@dataclass(frozen=True)
class CommandReport:
    """What became of a position command: joints applied and joints clamped to a limit."""

    applied: tuple[str, ...]
    clamped: tuple[str, ...]


class JointSim:
    """Every actuated joint of a description (rail, arm, gripper), position-controlled."""

    def __init__(self, desc: RobotDescription, initial: Mapping[str, float] | None = None) -> None:
        self.names = desc.all_joint_names
        limits = desc.limits_by_name()
        self.lower = np.array([limits[n][0] for n in self.names])
        self.upper = np.array([limits[n][1] for n in self.names])
        vel = {j.name: j.velocity for j in desc.joints}
        vel[desc.gripper.name] = desc.gripper.velocity
        if desc.rail:
            vel[desc.rail.name] = desc.rail.velocity
        self.vmax = np.array([vel[n] for n in self.names])
        self._index = {n: i for i, n in enumerate(self.names)}
        self.position = np.clip(np.zeros(len(self.names)), self.lower, self.upper)
        for name, value in (initial or {}).items():
            self.position[self._index[name]] = value
        self.goal = self.position.copy()
        self.velocity = np.zeros(len(self.names))

    def command(self, names: Sequence[str], positions: Sequence[float]) -> CommandReport:
        """Set position goals by name. Raises JointStateError (nothing applied) if invalid."""
        goals = check_command(names, positions, self.names)
        clamped = []
        for name, value in goals.items():
            i = self._index[name]
            limited = float(np.clip(value, self.lower[i], self.upper[i]))
            if limited != value:
                clamped.append(name)
            self.goal[i] = limited
        return CommandReport(applied=tuple(goals), clamped=tuple(clamped))

    def hold(self) -> None:
        """Stop where the joints are now."""
        self.goal = self.position.copy()

    def step(self, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds."""
        if dt <= 0.0:
            return
        err = self.goal - self.position
        move = np.clip(err, -self.vmax * dt, self.vmax * dt)
        self.position = self.position + move
        self.velocity = move / dt
