"""Task sequences as plain data, and the logic that decides when a stage is done (no ROS).

A task is a list of :class:`Stage`: joint-space goals by joint name (rad, m) that the task
node streams on ``joint_command`` until every listed joint is within ``tolerance`` of its
goal, or fails the task after ``timeout`` seconds. Cartesian tasks (pick-and-place) will add
stages whose goals come from the IK service.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Callable, Mapping

from hyperarm_description.model import RobotDescription

__all__ = ["TaskError", "UnknownTaskError", "Stage", "StageStatus", "stage_status",
           "TASKS", "build_task"]


class TaskError(Exception):
    """Root of the task errors."""


class UnknownTaskError(TaskError):
    """The requested task name is not one of ``TASKS``."""


@dataclass(frozen=True)
class Stage:
    """Drive ``goal`` joints (rad, or m for the rail) to within ``tolerance``; fail after
    ``timeout`` s."""

    name: str
    goal: Mapping[str, float]
    tolerance: float = 0.01
    timeout: float = 10.0

    def __post_init__(self) -> None:
        if not self.goal:
            raise ValueError(f"stage {self.name!r}: empty goal")
        if not (self.tolerance > 0 and math.isfinite(self.tolerance)):
            raise ValueError(f"stage {self.name!r}: tolerance must be > 0")
        if not (self.timeout > 0 and math.isfinite(self.timeout)):
            raise ValueError(f"stage {self.name!r}: timeout must be > 0")


class StageStatus(Enum):
    RUNNING = "running"
    DONE = "done"
    TIMED_OUT = "timed_out"


def stage_status(stage: Stage, positions: Mapping[str, float], elapsed: float) -> StageStatus:
    """DONE when every goal joint is known and within tolerance; TIMED_OUT after the
    stage's timeout; else RUNNING."""
    done = all(n in positions and abs(positions[n] - g) <= stage.tolerance
               for n, g in stage.goal.items())
    if done:
        return StageStatus.DONE
    return StageStatus.TIMED_OUT if elapsed > stage.timeout else StageStatus.RUNNING


def _ready(desc: RobotDescription) -> list[Stage]:
    """Open the gripper, then the ready pose q = 0 (arm stretched along base x)."""
    stages = [Stage("open_gripper", {desc.gripper.name: desc.gripper.upper}, tolerance=0.02,
                    timeout=5.0),
              Stage("ready_pose", {n: 0.0 for n in desc.arm_joint_names}, timeout=15.0)]
    if desc.rail:
        stages.append(Stage("rail_centre", {desc.rail.name: 0.0}, tolerance=0.002, timeout=15.0))
    return stages


def _rest(desc: RobotDescription) -> list[Stage]:
    """A folded, low-torque rest pose (shoulder and elbow bent), gripper closed."""
    goal = {n: 0.0 for n in desc.arm_joint_names}
    goal.update({desc.joints[1].name: math.radians(90), desc.joints[3].name: math.radians(-90)})
    return [Stage("close_gripper", {desc.gripper.name: desc.gripper.lower}, tolerance=0.02,
                  timeout=5.0),
            Stage("rest_pose", goal, timeout=15.0)]


TASKS: dict[str, Callable[[RobotDescription], list[Stage]]] = {"ready": _ready, "rest": _rest}


def build_task(name: str, desc: RobotDescription) -> list[Stage]:
    """Stages of task ``name``; raises UnknownTaskError listing the known tasks."""
    try:
        factory = TASKS[name]
    except KeyError:
        raise UnknownTaskError(
            f"unknown task {name!r}; known tasks: {', '.join(sorted(TASKS))}") from None
    return factory(desc)
