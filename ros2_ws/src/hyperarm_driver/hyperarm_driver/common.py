"""Helpers shared by the hardware driver nodes (imports rclpy: for nodes only).

:func:`declare_parameters` (from hyperarm_description.params, re-exported here) declares a
node's read-only parameters from one table and validates them. :func:`diagnostic_status` builds one DiagnosticStatus.
:func:`answer_set_torque` and :func:`answer_reboot` fill the ``set_torque`` and ``reboot``
responses the same way for every driver (the mock included), so a client cannot tell them
apart.
"""
from __future__ import annotations

from typing import Any, Callable, Iterable

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node

# The parameter table helpers live in hyperarm_description.params (shared by every node);
# re-exported here for the driver nodes.
from hyperarm_description.params import (NonEmpty, OneOf, ParamSpec, Range,  # noqa: F401
                                         declare_parameters)

__all__ = ["Range", "OneOf", "NonEmpty", "ParamSpec", "declare_parameters",
           "diagnostic_status", "answer_set_torque", "answer_reboot"]


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
