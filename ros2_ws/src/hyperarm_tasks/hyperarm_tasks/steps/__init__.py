"""The step registry: one module per step type (no ROS).

Each module defines a :class:`StepType`: its name, the JSON schema of its own fields, a
``build`` that turns the validated YAML mapping into a typed, SI-unit step, and a ``run``
that executes it against a :class:`hyperarm_tasks.runner.Runner`. Adding a step type is one
module plus one line in ``_MODULES`` below.
"""
from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from hyperarm_description.model import RobotDescription

from ..units import QUANTITY_PATTERN, UnitError, to_si

__all__ = ["Step", "StepType", "BuildContext", "PoseSpec", "Retry", "STEP_TYPES",
           "task_schema", "quantity", "pose_schema", "register"]

STALE_STATES = 0.05   # s: joint_states older than this say nothing of the joints now (the
                      # driver stalls, a node is not scheduled): paths hold, settling waits

# Failure kinds a retry rule may name (StepFailed.kind).
FAILURE_KINDS = ("ik", "collision", "grasp", "grasp_lost", "insertion", "detection", "driver",
                 "timeout", "joint_fault", "condition", "tracking")


def quantity(dimension: str, description: str = "") -> dict:
    """Schema of a number (SI) or "<number> <unit>" string."""
    return {"description": f"{description} ({dimension})".strip(),
            "oneOf": [{"type": "number"}, {"type": "string", "pattern": QUANTITY_PATTERN}],
            "x-dimension": dimension}


def pose_schema() -> dict:
    return {"type": "object", "additionalProperties": False, "required": ["relative_to"],
            "properties": {
                "relative_to": {"type": "string", "minLength": 1,
                                "description": "object, named frame, root frame or 'tool'"},
                "offset": {"type": "array", "minItems": 3, "maxItems": 3,
                           "items": quantity("length")},
                "orientation": {"enum": ["down", "keep"]},
            }}


@dataclass(frozen=True)
class Retry:
    """On a failure of one of the kinds ``on`` (YAML ``when``; empty = any), go back to step
    ``from_index`` (this step by default), at most ``attempts`` times; with ``clear`` (m) > 0
    the gripper opens and the tool moves straight up by that much first."""

    attempts: int = 0
    from_index: int = 0
    on: tuple[str, ...] = ()
    clear: float = 0.0


@dataclass(frozen=True)
class PoseSpec:
    """A tool0 target: ``relative_to`` an object (detected or given), a named frame, the
    root frame or ``tool`` (the current tool pose), plus ``offset`` (m, root-frame axes);
    orientation ``down`` (hand pointing down) or ``keep`` (the current one)."""

    relative_to: str
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: str = "down"

    def describe(self) -> str:
        off = ", ".join(f"{v:+.3f}" for v in self.offset)
        return f"{self.relative_to} + ({off}) m"


@dataclass(frozen=True)
class Step:
    """Fields every step has; step types subclass this with their own (SI units)."""

    name: str
    type: str
    index: int
    timeout: float
    retry: Retry = field(default_factory=Retry)
    description: str = ""


@dataclass
class BuildContext:
    """What ``build`` checks against: the description, declared objects, named frames."""

    desc: RobotDescription
    objects: tuple[str, ...]
    frames: dict[str, tuple[float, float, float]]
    step_names: list[str]

    class FieldError(ValueError):
        """A field's value is wrong; ``path`` is relative to the step (for the line)."""

        def __init__(self, path: Sequence, message: str) -> None:
            self.path = tuple(path)
            super().__init__(message)

    def si(self, raw: dict, key: str, dimension: str, default: float | None = None, *,
           positive: bool = False, nonneg: bool = False, path: Sequence = ()) -> float:
        if key not in raw:
            if default is None:
                raise self.FieldError((*path, key), f"{key} is missing (required)")
            return default
        try:
            v = to_si(raw[key], dimension)
        except UnitError as exc:
            raise self.FieldError((*path, key), f"{key}: {exc}") from None
        if positive and not v > 0.0:
            raise self.FieldError((*path, key), f"{key} must be > 0, got {raw[key]!r}")
        if nonneg and v < 0.0:
            raise self.FieldError((*path, key), f"{key} must be >= 0, got {raw[key]!r}")
        return v

    @staticmethod
    def length_vector(values: Sequence) -> list[float]:
        return [to_si(v, "length") for v in values]

    def pose(self, raw: dict, key: str) -> PoseSpec:
        spec = raw[key]
        ref = spec["relative_to"]
        known = self.reference_names()
        if ref not in known:
            raise self.FieldError((key, "relative_to"),
                                  f"unknown object or frame {ref!r}; known: {', '.join(known)}")
        try:
            off = tuple(self.length_vector(spec.get("offset", [0, 0, 0])))
        except UnitError as exc:
            raise self.FieldError((key, "offset"), f"offset: {exc}") from None
        return PoseSpec(ref, off, spec.get("orientation", "down"))  # type: ignore[arg-type]

    def reference_names(self) -> list[str]:
        return [*self.objects, *self.frames, self.desc.root_frame, "tool"]

    def common(self, raw: dict, index: int, default_timeout: float) -> dict[str, Any]:
        timeout = self.si(raw, "timeout", "time", default_timeout, positive=True)
        retry = Retry(from_index=index)
        if "retry" in raw:
            r = raw["retry"]
            start = r.get("from", raw["name"])
            if start not in self.step_names[:index + 1]:
                raise self.FieldError(("retry", "from"),
                                      f"retry.from {start!r} is not this step or an earlier one")
            clear = self.si(r, "clear", "length", 0.0, nonneg=True, path=("retry",))
            retry = Retry(int(r["attempts"]), self.step_names.index(start),
                          tuple(r.get("when", ())), clear)
        return dict(name=raw["name"], type=raw["type"], index=index, timeout=timeout,
                    retry=retry, description=raw.get("description", ""))

    def joint_goal(self, raw: dict, key: str, allowed: Sequence[str]) -> dict[str, float]:
        limits = self.desc.limits_by_name()
        out = {}
        for name, value in raw[key].items():
            if name not in allowed:
                raise self.FieldError((key, name), f"unknown joint {name!r}; known: "
                                      f"{', '.join(allowed)}")
            dim = "length" if self.desc.rail and name == self.desc.rail.name else "angle"
            v = self.si(raw[key], name, dim, path=(key,))
            lo, hi = limits[name]
            if not lo - 1e-9 <= v <= hi + 1e-9:
                raise self.FieldError((key, name), f"{name} = {v:.4g} is outside its limits "
                                      f"[{lo:.4g}, {hi:.4g}]")
            out[name] = v
        return out


@dataclass(frozen=True)
class StepType:
    """A registered step type."""

    name: str
    schema: dict                  # properties of its own fields (JSON schema)
    required: tuple[str, ...]
    build: Callable[[dict, BuildContext, int], Step]
    run: Callable[[Any, Any], None]    # run(step, runner)
    summary: str = ""


STEP_TYPES: dict[str, StepType] = {}


def register(step_type: StepType) -> StepType:
    if step_type.name in STEP_TYPES:
        raise RuntimeError(f"step type {step_type.name!r} registered twice")
    STEP_TYPES[step_type.name] = step_type
    return step_type


_COMMON = {
    "name": {"type": "string", "pattern": r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$"},
    "type": {"type": "string"},
    "description": {"type": "string"},
    "variant": {"enum": ["arm", "rail_arm"], "description": "run only on this variant"},
    "timeout": quantity("time", "the step fails after this"),
    "retry": {"type": "object", "additionalProperties": False, "required": ["attempts"],
              "properties": {"attempts": {"type": "integer", "minimum": 0, "maximum": 20},
                             "from": {"type": "string"},
                             "when": {"type": "array", "items": {"enum": list(FAILURE_KINDS)}},
                             "clear": quantity("length", "open the gripper and move the "
                                                         "tool up this much first")}},
}


def task_schema() -> dict:
    """JSON schema (draft 2020-12) of a whole task file, from the registered step types."""
    branches = []
    for st in STEP_TYPES.values():
        props = dict(_COMMON)
        props.update(st.schema)
        props["type"] = {"const": st.name}
        branches.append({"type": "object", "additionalProperties": False,
                         "required": ["name", "type", *st.required], "properties": props,
                         "if": {"properties": {"type": {"const": st.name}}}})
    # if/then per type: errors come from the step's own branch only.
    step = {"type": "object", "required": ["name", "type"],
            "properties": {"type": {"enum": sorted(STEP_TYPES)}},
            "allOf": [{"if": {"properties": {"type": {"const": b["properties"]["type"]["const"]}},
                              "required": ["type"]},
                       "then": {k: v for k, v in b.items() if k != "if"}} for b in branches]}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "type": "object", "additionalProperties": False,
            "required": ["schema_version"],
            "oneOf": [{"required": ["steps"], "not": {"required": ["extends"]}},
                      {"required": ["extends"], "not": {"required": ["steps"]}}],
            "properties": {
                "schema_version": {"type": "integer"},
                "description": {"type": "string"},
                "objects": {"type": "array", "items": {"type": "string"}, "uniqueItems": True},
                "frames": {"type": "object", "additionalProperties": {
                    "type": "object", "additionalProperties": False, "required": ["xyz"],
                    "properties": {"xyz": {"type": "array", "minItems": 3, "maxItems": 3,
                                           "items": quantity("length")}}}},
                "steps": {"type": "array", "minItems": 1, "items": step},
                "extends": {"type": "string", "description": "another task's steps"},
                "rename": {"type": "object", "additionalProperties": {"type": "string"},
                           "description": "objects/frames renamed in the extended steps"},
            }}


def finite(v: float) -> bool:
    return math.isfinite(v)


_MODULES = ("move_to", "move_joints", "gripper", "force_insert", "wait_for", "home_rail",
            "retreat", "track_path", "locate")
for _m in _MODULES:
    importlib.import_module(f"{__name__}.{_m}")
