"""``wait_for``: until a detection is fresh, or a condition on a joint state or the wrench
holds, or fail after the step's timeout.

    - {name: see_block, type: wait_for, detection: block, timeout: 5 s}
    - {name: gripper_open, type: wait_for, joint: {name: gripper, above: 1.0}}
    - {name: contact, type: wait_for, wrench: {axis: fz, below: -2 N}}
"""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import StepFailed
from . import BuildContext, Step, StepType, register

_AXES = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass(frozen=True)
class WaitFor(Step):
    detection: str | None = None
    joint: str | None = None
    axis: str | None = None
    above: float | None = None
    below: float | None = None


def build(raw: dict, ctx: BuildContext, index: int) -> WaitFor:
    kinds = [k for k in ("detection", "joint", "wrench") if k in raw]
    if len(kinds) != 1:
        raise ctx.FieldError((), "give exactly one of detection, joint, wrench")
    common = ctx.common(raw, index, 10.0)
    if kinds[0] == "detection":
        if raw["detection"] not in ctx.objects:
            raise ctx.FieldError(("detection",), f"unknown object {raw['detection']!r}; "
                                 f"declared objects: {', '.join(ctx.objects) or '(none)'}")
        return WaitFor(**common, detection=raw["detection"])
    spec = raw[kinds[0]]
    if kinds[0] == "joint":
        if spec["name"] not in ctx.desc.all_joint_names:
            raise ctx.FieldError(("joint", "name"), f"unknown joint {spec['name']!r}")
        dim, kw = "angle", dict(joint=spec["name"])
    else:
        dim = "force" if spec["axis"].startswith("f") else "torque"
        kw = dict(axis=spec["axis"])
    above = ctx.si(spec, "above", dim, path=(kinds[0],)) if "above" in spec else None
    below = ctx.si(spec, "below", dim, path=(kinds[0],)) if "below" in spec else None
    if above is None and below is None:
        raise ctx.FieldError((kinds[0],), "give above and/or below")
    return WaitFor(**common, above=above, below=below, **kw)


def _value(step: WaitFor, runner) -> float | None:
    if step.joint is not None:
        return runner.robot.joint_positions().get(step.joint)
    w = runner.robot.wrench()
    return None if w is None else float(w[_AXES.index(step.axis)])


def run(step: WaitFor, runner) -> None:
    if step.detection is not None:
        runner.detect(step.detection, timeout=step.timeout)
        return
    t0 = runner.robot.now()
    while True:
        v = _value(step, runner)
        if v is not None and (step.above is None or v > step.above) and \
                (step.below is None or v < step.below):
            return
        if runner.robot.now() - t0 > step.timeout:
            what = step.joint or step.axis
            seen = "no data" if v is None else f"last {v:.4g}"
            raise StepFailed("condition", f"{what} condition (above {step.above}, below "
                             f"{step.below}) not met in {step.timeout:g} s ({seen})")
        runner.feedback("waiting", min((runner.robot.now() - t0) / step.timeout, 0.99))
        runner.tick()


_LIMITS = {"above": {"oneOf": [{"type": "number"}, {"type": "string"}]},
           "below": {"oneOf": [{"type": "number"}, {"type": "string"}]}}
register(StepType(
    "wait_for",
    {"detection": {"type": "string"},
     "joint": {"type": "object", "additionalProperties": False, "required": ["name"],
               "properties": {"name": {"type": "string"}, **_LIMITS}},
     "wrench": {"type": "object", "additionalProperties": False, "required": ["axis"],
                "properties": {"axis": {"enum": list(_AXES)}, **_LIMITS}}},
    (), build, run, "wait for a detection or a condition"))
