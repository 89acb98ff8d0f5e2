"""Task files: load a YAML sequence, validate it, build the step list (no ROS).

A task is one YAML file (``<name>.yaml``) in a task directory: the package's share
directory ``share/hyperarm_tasks/tasks`` and any user directories (the task node's
``tasks_dir`` parameter, searched first). The file is checked against a JSON schema made
from the step registry (:mod:`hyperarm_tasks.steps`), then every value is converted to SI
units and checked against the robot description (joint names and limits, objects, frames).
Every error names the file, the line and the reason::

    my_task.yaml:12: steps[2] (down): unknown step type 'move_too'; known: gripper, ...

See docs/tasks.md for the format and every step type.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from hyperarm_description.model import RobotDescription

from .errors import TaskFileError, UnknownTaskError
from .steps import STEP_TYPES, BuildContext, Step, task_schema
from .units import UnitError

__all__ = ["Task", "load_task", "load_task_file", "task_names", "packaged_tasks_dir",
           "SCHEMA_VERSION"]

SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Task:
    """A validated task: its steps, and the objects and frames it refers to."""

    name: str
    source: str
    description: str
    steps: tuple[Step, ...]
    objects: tuple[str, ...] = ()
    frames: dict[str, tuple[float, float, float]] = field(default_factory=dict)


def packaged_tasks_dir() -> Path:
    """``share/hyperarm_tasks/tasks`` of the installed package (else the source tree's)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        path = Path(get_package_share_directory("hyperarm_tasks")) / "tasks"
        if path.is_dir():
            return path
    except (ImportError, LookupError, ValueError):
        pass
    return Path(__file__).resolve().parent.parent / "tasks"


def _dirs(extra: list[str | os.PathLike] | None) -> list[Path]:
    return [Path(d) for d in (extra or []) if str(d)] + [packaged_tasks_dir()]


def task_names(extra_dirs: list[str | os.PathLike] | None = None) -> list[str]:
    """Every task name found in the user directories and the package's."""
    names: set[str] = set()
    for d in _dirs(extra_dirs):
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.yaml"))
    return sorted(names)


def find_task(name: str, extra_dirs: list[str | os.PathLike] | None = None) -> Path:
    """Path of ``<name>.yaml`` (user directories first); UnknownTaskError lists the known."""
    if not name or "/" in name or name.startswith("."):
        raise UnknownTaskError(f"bad task name {name!r}")
    for d in _dirs(extra_dirs):
        path = d / f"{name}.yaml"
        if path.is_file():
            return path
    raise UnknownTaskError(f"unknown task {name!r}; known tasks: "
                           f"{', '.join(task_names(extra_dirs)) or '(none)'}")


def load_task(name: str, desc: RobotDescription,
              extra_dirs: list[str | os.PathLike] | None = None) -> Task:
    """Find ``<name>.yaml`` (user directories first) and load it; UnknownTaskError lists
    the known tasks."""
    return load_task_file(find_task(name, extra_dirs), desc, extra_dirs)


# --- YAML with line numbers ----------------------------------------------------------------
def _compose(text: str, where: str) -> tuple[Any, dict[tuple, int]]:
    """Parse ``text``; returns the data and {path tuple: line (1-based)} of every node."""
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise TaskFileError(where, 1, "empty file")
        lines: dict[tuple, int] = {}

        def build(n: yaml.Node, path: tuple) -> Any:
            lines[path] = n.start_mark.line + 1
            if isinstance(n, yaml.MappingNode):
                out: dict[Any, Any] = {}
                for k, v in n.value:
                    key = loader.construct_object(k, deep=True)
                    if key in out:
                        raise TaskFileError(where, k.start_mark.line + 1,
                                            f"duplicate key {key!r}")
                    lines[path + (key,)] = k.start_mark.line + 1
                    out[key] = build(v, path + (key,))
                    lines[path + (key,)] = v.start_mark.line + 1
                return out
            if isinstance(n, yaml.SequenceNode):
                return [build(v, path + (i,)) for i, v in enumerate(n.value)]
            return loader.construct_object(n, deep=True)

        return build(node, ()), lines
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        raise TaskFileError(where, mark.line + 1 if mark else None,
                            f"YAML syntax: {exc.problem or exc}") from None
    finally:
        loader.dispose()


def _line(lines: dict[tuple, int], path: tuple) -> int | None:
    path = tuple(path)
    while path not in lines and path:
        path = path[:-1]
    return lines.get(path)


def _label(data: Any, path: tuple) -> str:
    """``steps[2] (down)`` for a path inside a step, else the dotted path."""
    if len(path) >= 2 and path[0] == "steps" and isinstance(path[1], int):
        try:
            name = data["steps"][path[1]].get("name", "?")
        except (AttributeError, IndexError, KeyError, TypeError):
            name = "?"
        rest = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path[2:])
        return f"steps[{path[1]}] ({name}){rest}"
    return ".".join(str(p) for p in path) or "file"


def _schema_message(err: jsonschema.ValidationError) -> str:
    if err.validator == "additionalProperties":
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        return (f"unknown field {', '.join(map(repr, extra))}; allowed: "
                f"{', '.join(sorted(err.schema.get('properties', {})))}")
    if err.validator == "required":
        return err.message.replace("is a required property", "is missing (required)")
    if err.validator == "enum":
        return f"{err.instance!r} is not one of {', '.join(map(str, err.validator_value))}"
    return err.message


def _schema_error(data: Any, where: str, lines: dict, err: jsonschema.ValidationError) -> None:
    path = tuple(err.absolute_path)
    # A step with an unknown type: say so plainly instead of listing every oneOf branch.
    if len(path) >= 2 and path[0] == "steps" and isinstance(path[1], int):
        step = data["steps"][path[1]]
        if isinstance(step, dict) and step.get("type") not in STEP_TYPES:
            kind = step.get("type")
            reason = ("missing 'type'" if kind is None else
                      f"unknown step type {kind!r}") + f"; known: {', '.join(sorted(STEP_TYPES))}"
            raise TaskFileError(where, _line(lines, path[:2] + ("type",)),
                                f"{_label(data, path[:2])}: {reason}")
    at = path
    if err.validator == "additionalProperties" and isinstance(err.instance, dict):
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})), key=str)
        at = path + (extra[0],) if extra else path
    raise TaskFileError(where, _line(lines, at), f"{_label(data, path)}: {_schema_message(err)}")


def _best(errors: list[jsonschema.ValidationError]) -> jsonschema.ValidationError:
    """The deepest error (inside the branch of the step's own type)."""
    err = jsonschema.exceptions.best_match(errors)
    while err.context:
        err = max(err.context, key=lambda e: len(e.absolute_path))
    return err


def _read_checked(path: Path) -> tuple[Any, dict]:
    where = path.name
    try:
        text = path.read_text()
    except OSError as exc:
        raise TaskFileError(where, None, f"cannot read: {exc.strerror or exc}") from None
    data, lines = _compose(text, where)
    validator = jsonschema.Draft202012Validator(task_schema())
    errors = sorted(validator.iter_errors(data), key=lambda e: len(e.absolute_path))
    if errors:
        if isinstance(data, dict) and ("steps" in data) == ("extends" in data):
            raise TaskFileError(where, 1, "give either 'steps' or 'extends' (another task)")
        _schema_error(data, where, lines, _best(errors))
    if data["schema_version"] != SCHEMA_VERSION:
        raise TaskFileError(where, _line(lines, ("schema_version",)),
                            f"schema_version {data['schema_version']} is not supported "
                            f"(this version reads {SCHEMA_VERSION})")
    return data, lines


def _renamed(value: Any, rename: dict[str, str]) -> Any:
    if isinstance(value, dict):
        return {k: (rename.get(v, v) if k in ("relative_to", "detection") and isinstance(v, str)
                    else [rename.get(o, o) for o in v] if k == "objects" and isinstance(v, list)
                    else _renamed(v, rename)) for k, v in value.items()}
    if isinstance(value, list):
        return [_renamed(v, rename) for v in value]
    return value


def load_task_file(path: str | os.PathLike, desc: RobotDescription,
                   extra_dirs: list[str | os.PathLike] | None = None) -> Task:
    """Load and validate one task file; raises TaskFileError (file:line: reason).

    A file with ``extends: other`` takes the other task's steps, objects and frames, with
    the object and frame names of ``rename`` swapped (e.g. the transfer back)."""
    path = Path(path)
    where = path.name
    data, lines = _read_checked(path)
    if "extends" in data:
        try:
            base_path = find_task(data["extends"], extra_dirs)
        except UnknownTaskError as exc:
            raise TaskFileError(where, _line(lines, ("extends",)), str(exc)) from None
        if base_path.resolve() == path.resolve():
            raise TaskFileError(where, _line(lines, ("extends",)), "a task cannot extend itself")
        base, base_lines = _read_checked(base_path)
        if "extends" in base:
            raise TaskFileError(where, _line(lines, ("extends",)),
                                f"{base_path.name} extends another task itself (one level only)")
        rename = data.get("rename", {})
        unknown = sorted(set(rename) - set(base.get("objects", [])) - set(base.get("frames", {})))
        if unknown:
            raise TaskFileError(where, _line(lines, ("rename",)),
                                f"rename: {', '.join(unknown)} not objects or frames of "
                                f"{base_path.name}")
        merged = dict(base)
        merged["steps"] = _renamed(base["steps"], rename)
        merged["description"] = data.get("description", base.get("description", ""))
        data, lines, where = merged, base_lines, f"{where} (extends {base_path.name})"
    frames = {}
    for fname, spec in data.get("frames", {}).items():
        try:
            frames[fname] = tuple(BuildContext.length_vector(spec["xyz"]))
        except UnitError as exc:
            raise TaskFileError(where, _line(lines, ("frames", fname, "xyz")),
                                f"frames.{fname}.xyz: {exc}") from None
    ctx = BuildContext(desc=desc, objects=tuple(data.get("objects", [])), frames=frames,
                       step_names=[s["name"] for s in data["steps"]
                                   if s.get("variant", desc.variant) == desc.variant])
    seen: set[str] = set()
    steps = []
    for i, raw in enumerate(data["steps"]):
        if raw.get("variant", desc.variant) != desc.variant:
            continue  # a step for another variant (its joints are not in this description)
        if raw["name"] in seen:
            raise TaskFileError(where, _line(lines, ("steps", i, "name")),
                                f"{_label(data, ('steps', i))}: duplicate step name")
        seen.add(raw["name"])
        try:
            steps.append(STEP_TYPES[raw["type"]].build(raw, ctx, len(steps)))
        except BuildContext.FieldError as exc:
            raise TaskFileError(where, _line(lines, ("steps", i, *exc.path)),
                                f"{_label(data, ('steps', i, *exc.path))}: {exc}") from None
    return Task(name=path.stem, source=str(path), description=data.get("description", ""),
                steps=tuple(steps), objects=ctx.objects, frames=frames)
