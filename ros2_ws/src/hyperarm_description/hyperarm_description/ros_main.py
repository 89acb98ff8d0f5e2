"""The one `main()` of every hyperarm node (imports rclpy: for nodes only).

The ros2/demos pattern, written once: init, build the node, spin, and on Ctrl-C / SIGTERM
(KeyboardInterrupt or ExternalShutdownException) destroy the node and shut down cleanly.
A node constructor that raises SystemExit (bad parameters, bad description) ends the
process with that message and exit code 1, after the same clean-up.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

if TYPE_CHECKING:
    from .model import RobotDescription

__all__ = ["run_node", "declare_robot_description"]


def run_node(factory: Callable[[], Node], args: list[str] | None = None,
             executor: Callable[[], Executor] | None = None) -> None:
    """Spin the node made by ``factory`` until shutdown; ``executor`` builds a custom one."""
    context = rclpy.get_default_context()
    rclpy.init(args=args, context=context)
    node = None
    ex = executor() if executor is not None else None
    try:
        node = factory()
        if ex is None:
            rclpy.spin(node)
        else:
            ex.add_node(node)
            ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # Ctrl-C shuts the context down while callbacks may still be running: a publish or
        # a wait set made in that window fails with an RCLError. That is the shutdown, not
        # a bug; an exception while the context is still up is one, and is raised.
        if context.ok():
            raise
    finally:
        if ex is not None:
            ex.shutdown(timeout_sec=2.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def declare_robot_description(node: Node) -> "RobotDescription":
    """Declare the common read-only parameters ``variant`` and ``description_file`` on
    ``node`` and load the description they name. Raises SystemExit with the reason if the
    variant or the file is bad (the node cannot run without its robot)."""
    from rcl_interfaces.msg import ParameterDescriptor

    from .model import VARIANTS, DescriptionError, load_description

    node.declare_parameter("variant", "arm", ParameterDescriptor(
        description=f"robot variant: {' or '.join(VARIANTS)}", read_only=True))
    node.declare_parameter("description_file", "", ParameterDescriptor(
        description="robot description YAML ('' = the packaged config/hyperarm.yaml)",
        read_only=True))
    variant = node.get_parameter("variant").value
    path = node.get_parameter("description_file").value or None
    try:
        return load_description(path, variant)
    except DescriptionError as exc:
        raise SystemExit(f"{node.get_name()}: {exc}") from exc
