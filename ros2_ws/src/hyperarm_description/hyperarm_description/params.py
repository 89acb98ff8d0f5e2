"""Node parameters declared from one table: name -> (default, description, check).

A table (:data:`ParamSpec`) is declared by :func:`declare_parameters` (read-only, with its
description and bounds, every value validated: a wrong value *or a wrong type*, e.g. ``-p
rate:=50`` for a float, ends the node with a clear message instead of a traceback) and
printed by :func:`format_parameters` for a node's ``--help``, so the two cannot drift apart.
The checks (:class:`Range`, :class:`OneOf`, :class:`NonEmpty`) are plain Python; only
:func:`declare_parameters` needs rclpy, imported when it is called.
"""
from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:
    from rclpy.node import Node

__all__ = ["Range", "OneOf", "NonEmpty", "ParamSpec", "declare_parameters",
           "format_parameters"]


@dataclass(frozen=True)
class Range:
    """Inclusive numeric bounds."""

    lo: float
    hi: float

    def check(self, value: Any) -> str | None:
        return None if self.lo <= value <= self.hi else f"not within {self.lo:g}..{self.hi:g}"

    def text(self) -> str:
        return f" [{self.lo:g}..{self.hi:g}]"


@dataclass(frozen=True)
class OneOf:
    """One of a few allowed values."""

    values: tuple

    def check(self, value: Any) -> str | None:
        return None if value in self.values else f"not one of {', '.join(map(str, self.values))}"

    def text(self) -> str:
        return f" (one of {', '.join(map(str, self.values))})"


@dataclass(frozen=True)
class NonEmpty:
    """A string that must not be empty."""

    def check(self, value: Any) -> str | None:
        return None if value else "must not be empty"

    def text(self) -> str:
        return ""


Check = Range | OneOf | NonEmpty
# name -> (default, description, check or None); the default's type is the parameter's type
ParamSpec = Mapping[str, tuple[Any, str, "Check | None"]]

_TYPE_NAMES = {bool: "a bool (true/false)", int: "an integer", float: "a number",
               str: "a string"}


def _coerce(value: Any, default: Any) -> Any:
    """``value`` as the type of ``default`` (an integer is accepted for a float), or raise
    TypeError."""
    want = type(default)
    if want is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if type(value) is not want:
        raise TypeError(_TYPE_NAMES.get(want, want.__name__))
    return value


def declare_parameters(node: "Node", table: ParamSpec) -> dict[str, Any]:
    """Declare every parameter of ``table`` read-only with its description (bounds appended)
    and return their values. Raises SystemExit naming the node and the parameter if a value
    has the wrong type, is not finite (floats) or fails its check."""
    from rcl_interfaces.msg import ParameterDescriptor

    out: dict[str, Any] = {}
    for name, (default, text, check) in table.items():
        descriptor = ParameterDescriptor(
            description=text + (check.text() if check is not None else ""), read_only=True,
            dynamic_typing=True)   # a wrong type is reported below, not raised by rclpy
        raw = node.declare_parameter(name, default, descriptor).value
        try:
            value = _coerce(raw, default)
        except TypeError as exc:
            raise SystemExit(f"{node.get_name()}: parameter {name} must be {exc}, "
                             f"got {raw!r}") from None
        problem = None
        if isinstance(value, float) and not math.isfinite(value):
            problem = "must be finite"
        elif check is not None:
            problem = check.check(value)
        if problem:
            raise SystemExit(f"{node.get_name()}: parameter {name}={value!r} {problem}")
        out[name] = value
    return out


def _type_name(default: Any) -> str:
    return {bool: "bool", int: "int", float: "float", str: "string"}.get(type(default),
                                                                       type(default).__name__)


def format_parameters(table: ParamSpec) -> str:
    """The parameters of ``table`` as ``--help`` text: name, type, default, description."""
    lines = []
    for name, (default, text, check) in table.items():
        shown = ("true" if default else "false") if isinstance(default, bool) else repr(default)
        lines.append(f"  {name} ({_type_name(default)}, default {shown})")
        lines += textwrap.wrap(text + (check.text() if check is not None else ""), width=88,
                               initial_indent="      ", subsequent_indent="      ")
    return "\n".join(lines)
