"""``move_joints``: joint-space goals by name (rad; m for the rail), until within
``tolerance`` or the step's timeout. ``arm: <angle>`` sets all nine arm joints at once.

    - name: ready_pose
      type: move_joints
      arm: 0
      joints: {gripper: 80 deg}
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import StepFailed
from . import BuildContext, Step, StepType, quantity, register

RAIL_STATE_WAIT = 3.0   # s, for the rail driver to report whether it is homed


@dataclass(frozen=True)
class MoveJoints(Step):
    goal: dict = field(default_factory=dict)
    tolerance: float = 0.01


def build(raw: dict, ctx: BuildContext, index: int) -> MoveJoints:
    goal: dict[str, float] = {}
    if "arm" in raw:
        v = ctx.si(raw, "arm", "angle")
        for j in ctx.desc.joints:
            if not j.lower <= v <= j.upper:
                raise ctx.FieldError(("arm",), f"arm = {v:.4g} is outside {j.name}'s limits")
            goal[j.name] = v
    if "joints" in raw:
        goal.update(ctx.joint_goal(raw, "joints", ctx.desc.all_joint_names))
    if not goal:
        raise ctx.FieldError(("joints",), "give 'joints' or 'arm'")
    return MoveJoints(**ctx.common(raw, index, 15.0), goal=goal,
                      tolerance=ctx.si(raw, "tolerance", "angle", 0.01, positive=True))


def run(step: MoveJoints, runner) -> None:
    rail = runner.desc.rail.name if runner.desc.rail else None
    goal = dict(step.goal)
    if rail and rail in goal:
        t0 = runner.robot.now()
        while runner.robot.rail_homed() is None and runner.robot.now() - t0 < RAIL_STATE_WAIT:
            runner.tick()          # the rail driver's first diagnostics
        if runner.robot.rail_homed() is False:
            raise StepFailed("driver", "driver refused: the rail is not homed (add a "
                                       "home_rail step first)")
    runner.move_joint_goal(goal, step.tolerance, step.timeout)


register(StepType(
    "move_joints",
    {"joints": {"type": "object", "minProperties": 1,
                "additionalProperties": quantity("angle")},
     "arm": quantity("angle"), "tolerance": quantity("angle")},
    (), build, run, "joint-space goals by name"))
