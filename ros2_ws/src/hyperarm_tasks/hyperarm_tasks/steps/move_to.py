"""``move_to``: a Cartesian straight line of tool0 to a pose, at a speed limit.

IK at every interpolated point (``spacing`` apart); if an intermediate point has no
solution but the target has, the move falls back to a joint-space line with a logged
reason (``joint_fallback: false`` makes that a failure). ``keep`` keeps coordinates of the
current tool target (e.g. ``[x, y]`` to go straight down from where an insertion ended).

    - name: above_source
      type: move_to
      target: {relative_to: source_peg, offset: [0, 0, 3.5 cm]}
      speed: 5 cm/s
"""
from __future__ import annotations

from dataclasses import dataclass

from . import BuildContext, PoseSpec, Step, StepType, pose_schema, quantity, register


@dataclass(frozen=True)
class MoveTo(Step):
    target: PoseSpec = PoseSpec("tool")
    speed: float = 0.05           # m/s, peak tool speed
    spacing: float = 0.005        # m between IK points
    tolerance: float = 0.003      # m, measured tool position to target
    joint_fallback: bool = True
    keep: tuple[str, ...] = ()
    effort: float | None = None   # N·m current limit of the arm joints (None = default)


def build(raw: dict, ctx: BuildContext, index: int) -> MoveTo:
    return MoveTo(**ctx.common(raw, index, 20.0), target=ctx.pose(raw, "target"),
                  speed=ctx.si(raw, "speed", "speed", 0.05, positive=True),
                  spacing=ctx.si(raw, "spacing", "length", 0.005, positive=True),
                  tolerance=ctx.si(raw, "tolerance", "length", 0.003, positive=True),
                  joint_fallback=bool(raw.get("joint_fallback", True)),
                  keep=tuple(raw.get("keep", ())),
                  effort=(ctx.si(raw, "effort", "torque", positive=True)
                          if "effort" in raw else None))


def target_of(step, runner):
    target = runner.resolve(step.target)
    if step.keep:
        ref = runner.tool_reference()
        for axis in step.keep:
            k = "xyz".index(axis)
            target[k, 3] = ref[k, 3]
    return target


def run(step: MoveTo, runner) -> None:
    target = target_of(step, runner)
    efforts = ({n: step.effort for n in runner.desc.arm_joint_names}
               if step.effort is not None else None)
    runner.move_line(target, step.speed, step.spacing, step.tolerance, step.timeout,
                     step.joint_fallback, f"{step.name} (to {step.target.describe()})", efforts)


register(StepType(
    "move_to",
    {"target": pose_schema(), "speed": quantity("speed"), "spacing": quantity("length"),
     "tolerance": quantity("length"), "joint_fallback": {"type": "boolean"},
     "keep": {"type": "array", "items": {"enum": ["x", "y", "z"]}, "uniqueItems": True},
     "effort": quantity("torque")},
    ("target",), build, run, "Cartesian straight line of tool0 to a pose"))
