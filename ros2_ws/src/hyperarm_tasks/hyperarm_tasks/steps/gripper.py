"""``gripper``: open, or close with an effort (current limit); a close with
``expect: grasp`` checks the grasp from the gripper's position (not closed on nothing) and
effort (at the limit: pressing on the block), then the runner watches it until an open.

    - name: close
      type: gripper
      action: close
      effort: 0.6 N·m
      expect: grasp
"""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import StepFailed
from . import BuildContext, Step, StepType, quantity, register


@dataclass(frozen=True)
class Gripper(Step):
    action: str = "open"
    position: float | None = None   # rad (open: default the upper limit; close: 0)
    effort: float | None = None     # N·m
    expect: str = "none"            # "grasp" | "empty" | "none"


def build(raw: dict, ctx: BuildContext, index: int) -> Gripper:
    g = ctx.desc.gripper
    pos = None
    if "position" in raw:
        pos = ctx.si(raw, "position", "angle")
        if not g.lower <= pos <= g.upper:
            raise ctx.FieldError(("position",), f"position {pos:.4g} rad outside the gripper's "
                                 f"[{g.lower:g}, {g.upper:.4g}]")
    effort = ctx.si(raw, "effort", "torque", positive=True) if "effort" in raw else None
    if raw["action"] == "close" and effort is None:
        effort = g.grip_effort
    return Gripper(**ctx.common(raw, index, 5.0), action=raw["action"], position=pos,
                   effort=effort, expect=raw.get("expect", "none"))


def run(step: Gripper, runner) -> None:
    g = runner.desc.gripper
    p = runner.params
    if step.action == "open":
        runner.release_grasp()     # what was held may be anywhere now: forgotten
        goal = g.upper if step.position is None else step.position
        runner.move_joint_goal({g.name: goal}, 0.02, step.timeout,
                               {g.name: step.effort} if step.effort else None, "opening")
        return
    # what the fingers close on may move: its located pose is forgotten (only sightings
    # taken from now on place it again)
    gone = runner.touch(runner.tool_position_or_none()) if runner.located else []
    if gone:
        runner.robot.log("info", f"{step.name}: {', '.join(gone)} may move now; only fresh "
                                 f"sightings place {'it' if len(gone) == 1 else 'them'} again")
    goal = g.lower if step.position is None else step.position
    runner.move_joint_goal({g.name: goal}, 0.005, step.timeout, {g.name: step.effort},
                           "closing", settle_on_stop=True)
    pos = runner.robot.joint_positions().get(g.name, 0.0)
    eff = abs(runner.robot.joint_efforts().get(g.name, 0.0))
    held = pos >= p.grasp_min_position and eff >= p.grasp_min_effort_ratio * step.effort
    if step.expect == "grasp":
        if not held:
            raise StepFailed("grasp", f"grasp missed: the gripper closed to {pos:.3f} rad "
                             f"(empty below {p.grasp_min_position:g} rad) with {eff:.2f} N·m "
                             f"(a grasp needs >= {p.grasp_min_effort_ratio * step.effort:.2f})")
        runner.holding = step.effort
        runner.held_objects = set(gone)       # held: never located until released
        runner.metrics["grasp_position"] = pos
    elif step.expect == "empty" and held:
        raise StepFailed("grasp", f"something is between the fingers ({pos:.3f} rad)")


register(StepType(
    "gripper",
    {"action": {"enum": ["open", "close"]}, "position": quantity("angle"),
     "effort": quantity("torque"), "expect": {"enum": ["grasp", "empty", "none"]}},
    ("action",), build, run, "open, or close with an effort and check the grasp"))
