"""``retreat``: straight up (root +z, or ``direction``) by ``distance`` from the current
tool target, at a speed limit (a ``move_to`` relative to the tool).

    - name: up
      type: retreat
      distance: 5 cm
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import BuildContext, Step, StepType, quantity, register


@dataclass(frozen=True)
class Retreat(Step):
    distance: float = 0.05
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    speed: float = 0.05
    tolerance: float = 0.003


def build(raw: dict, ctx: BuildContext, index: int) -> Retreat:
    d = np.asarray(raw.get("direction", [0, 0, 1]), dtype=float)
    if not np.linalg.norm(d) > 1e-9:
        raise ctx.FieldError(("direction",), "direction must not be zero")
    return Retreat(**ctx.common(raw, index, 15.0),
                   distance=ctx.si(raw, "distance", "length", positive=True),
                   direction=tuple(d / np.linalg.norm(d)),
                   speed=ctx.si(raw, "speed", "speed", 0.05, positive=True),
                   tolerance=ctx.si(raw, "tolerance", "length", 0.003, positive=True))


def run(step: Retreat, runner) -> None:
    target = runner.tool_reference()
    target[:3, 3] += step.distance * np.asarray(step.direction)
    runner.move_line(target, step.speed, 0.005, step.tolerance, step.timeout, True,
                     f"{step.name} (retreat {step.distance * 100:.1f} cm)")


register(StepType(
    "retreat",
    {"distance": quantity("length"), "speed": quantity("speed"), "tolerance": quantity("length"),
     "direction": {"type": "array", "minItems": 3, "maxItems": 3, "items": {"type": "number"}}},
    ("distance",), build, run, "straight back from where the tool is"))
