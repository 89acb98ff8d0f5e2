"""run_node: the shared main() of every node (node tier: real rclpy, default context)."""
from __future__ import annotations

import pytest
import rclpy
from rclpy.node import Node

from hyperarm_description.ros_main import run_node

pytestmark = pytest.mark.node


class _Boom(Node):
    """A node whose timer raises, after shutting the context down when ``shutdown``."""

    def __init__(self, shutdown: bool) -> None:
        super().__init__("boom")
        self.shutdown_first = shutdown
        self.create_timer(0.01, self._tick)

    def _tick(self) -> None:
        if self.shutdown_first:
            rclpy.shutdown()  # what Ctrl-C does, as seen from a callback still running
        raise RuntimeError("callback failed")


def test_exception_while_context_is_up_is_raised(ros_domain):
    with pytest.raises(RuntimeError, match="callback failed"):
        run_node(lambda: _Boom(shutdown=False), [])
    assert not rclpy.ok()  # cleaned up all the same


def test_exception_after_shutdown_is_the_shutdown_not_a_bug(ros_domain):
    run_node(lambda: _Boom(shutdown=True), [])  # returns normally
    assert not rclpy.ok()


def test_constructor_systemexit_propagates_after_cleanup(ros_domain):
    def factory():
        raise SystemExit("node: bad parameter")

    with pytest.raises(SystemExit, match="bad parameter"):
        run_node(factory, [])
    assert not rclpy.ok()
