"""``locate``: the camera locates objects before the arm reaches over them.

    - {name: look, type: locate, objects: [block, source_peg, destination_peg], timeout: 5 s}

Waits (up to the step's timeout in all) for fresh sightings of each object (``objects``:
default every object the task declares; objects given with the goal are skipped) and keeps
where each is (:attr:`hyperarm_tasks.runner.Runner.located`). A later step's target relative
to one of them uses fresh sightings when the camera has them, else this located pose while
the object is untouched and at most ``located_max_age`` old (the arm's own links hide an
object from a fixed camera once the hand is over it). Fails with kind "detection", naming
the object not seen.
"""
from __future__ import annotations

from dataclasses import dataclass

from . import BuildContext, Step, StepType, register


@dataclass(frozen=True)
class Locate(Step):
    objects: tuple[str, ...] = ()


def build(raw: dict, ctx: BuildContext, index: int) -> Locate:
    names = tuple(raw.get("objects", ctx.objects))
    if not names:
        raise ctx.FieldError(("objects",), "no objects to locate: the task declares none")
    for k, name in enumerate(names):
        if name not in ctx.objects:
            raise ctx.FieldError(("objects", k), f"unknown object {name!r}; declared objects: "
                                 f"{', '.join(ctx.objects) or '(none)'}")
    return Locate(**ctx.common(raw, index, 5.0), objects=names)


def run(step: Locate, runner) -> None:
    t0 = runner.robot.now()
    for k, name in enumerate(step.objects):
        if runner.robot.given_object(name) is not None:
            continue
        runner.feedback("locating", k / len(step.objects))
        left = max(round(step.timeout - (runner.robot.now() - t0), 2), 0.1)   # (said: 4.87 s)
        est = runner.detect(name, timeout=left)
        xyz = ", ".join(f"{v:.3f}" for v in est.xyz)
        runner.robot.log("info", f"{step.name}: {name} located at ({xyz}) m ({est.used} frames)")


register(StepType(
    "locate",
    {"objects": {"type": "array", "minItems": 1, "uniqueItems": True,
                 "items": {"type": "string"}}},
    (), build, run, "locate objects with the camera before the arm hides them"))
