"""Helpers shared by the hardware driver nodes (imports rclpy: for nodes only).

:func:`declare_parameters` declares a node's read-only parameters from one table (default,
description, check) and validates them, so that a wrong value *or a wrong type* (``-p
rate:=50`` for a float parameter, ``-p port:=1e6`` for an int) ends the node with a clear
message instead of a traceback. :func:`diagnostic_status` builds one DiagnosticStatus.
:func:`answer_set_torque` and :func:`answer_reboot` fill the ``set_torque`` and ``reboot``
responses the same way for every driver (the mock included), so a client cannot tell them
apart.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

__all__ = ["Range", "OneOf", "NonEmpty", "ParamSpec", "declare_parameters",
           "diagnostic_status", "answer_set_torque", "answer_reboot"]


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


def declare_parameters(node: Node, table: ParamSpec) -> dict[str, Any]:
    """Declare every parameter of ``table`` read-only with its description (bounds appended)
    and return their values. Raises SystemExit naming the node and the parameter if a value
    has the wrong type, is not finite (floats) or fails its check."""
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


def diagnostic_status(name: str, hardware_id: str, level: int, message: str,
                      values: Iterable[tuple[str, Any]]) -> DiagnosticStatus:
    """One DiagnosticStatus; ``values`` are (key, value) pairs, values converted with str."""
    return DiagnosticStatus(level=bytes([level]), name=name, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=str(v)) for k, v in values])


def answer_set_torque(node: Node, enable: bool, action: Callable[[bool], Any],
                      errors: tuple[type[Exception], ...], response: Any) -> Any:
    """Run ``action(enable)`` for std_srvs/SetBool ``set_torque``: success, or
    success=false with the error's message (logged) when it raises one of ``errors``."""
    try:
        action(bool(enable))
    except errors as exc:
        response.success, response.message = False, f"set_torque {enable}: {exc}"
        node.get_logger().error(response.message)
        return response
    response.success, response.message = True, f"torque {'on' if enable else 'off'}"
    node.get_logger().info(response.message)
    return response


def answer_reboot(node: Node, joints: list[str], action: Callable[[list[str]], list[str]],
                  errors: tuple[type[Exception], ...], response: Any) -> Any:
    """Run ``action(joints)`` (returns the joints rebooted) for hyperarm_interfaces/Reboot."""
    try:
        response.rebooted = action(list(joints))
    except errors as exc:
        response.success, response.message = False, f"reboot: {exc}"
        node.get_logger().error(response.message)
        return response
    response.success = True
    response.message = (f"rebooted {response.rebooted} (torque off)" if response.rebooted
                        else "no joint in hardware error: nothing rebooted")
    node.get_logger().info(response.message)
    return response
