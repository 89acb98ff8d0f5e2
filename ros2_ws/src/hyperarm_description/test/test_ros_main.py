"""run_node: the shared main() of every node (node tier: real rclpy, default context)."""
from __future__ import annotations

import os
import signal
import threading

import pytest
import rclpy
from rclpy.node import Node

from hyperarm_description.ros_main import EXECUTORS, make_executor, run_node

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


@pytest.mark.parametrize("executor", [None, "events"])
def test_exception_while_context_is_up_is_raised(ros_domain, executor):
    with pytest.raises(RuntimeError, match="callback failed"):
        run_node(lambda: _Boom(shutdown=False), [], executor)
    assert not rclpy.ok()  # cleaned up all the same


@pytest.mark.parametrize("executor", [None, "events"])
def test_exception_after_shutdown_is_the_shutdown_not_a_bug(ros_domain, executor):
    run_node(lambda: _Boom(shutdown=True), [], executor)  # returns normally
    assert not rclpy.ok()


class _Served(Node):
    """A node with a Trigger service; ``executor`` declared as a parameter if given."""

    def __init__(self, executor: str | None) -> None:
        from rclpy.parameter import Parameter
        from std_srvs.srv import Trigger

        overrides = [] if executor is None else [Parameter("executor", value=executor)]
        super().__init__("served", parameter_overrides=overrides)
        if executor is not None:
            self.declare_parameter("executor", "single")
        self.create_service(Trigger, "served/ping", self._ping)

    def _ping(self, _req, res):
        res.success, res.message = True, type(self.executor).__name__
        return res


@pytest.mark.parametrize("choice,sig", [("events", signal.SIGINT), ("events", signal.SIGTERM),
                                        ("single", signal.SIGTERM),
                                        ("parameter-events", signal.SIGINT)],
                         ids=["events-sigint", "events-sigterm", "single-sigterm",
                              "parameter-events-sigint"])
def test_named_executor_serves_and_stops_on_signals(rclpy_context, wait_for, sig, choice):
    """run_node(executor=<name>): services work on that executor (the EventsExecutor has no
    guard conditions: the spin loop is woken another way), and SIGINT/SIGTERM end it
    cleanly. A node declaring ``executor`` chooses by that parameter."""
    from std_srvs.srv import Trigger

    param = "events" if choice == "parameter-events" else None
    answers: list[str] = []

    def client() -> None:
        node = rclpy.create_node("served_client", context=rclpy_context)
        try:
            cli = node.create_client(Trigger, "served/ping")
            if cli.wait_for_service(timeout_sec=20.0):
                fut = cli.call_async(Trigger.Request())
                rclpy.spin_until_future_complete(node, fut, timeout_sec=10.0)
                if fut.done():
                    answers.append(fut.result().message)
        finally:
            node.destroy_node()
            os.kill(os.getpid(), sig)        # what Ctrl-C / systemd do

    t = threading.Thread(target=client, daemon=True)
    t.start()
    run_node(lambda: _Served(param), [], "single" if param else choice,
             robot_description=False)     # returns: the signal stopped it
    t.join(5.0)
    assert not rclpy.ok()
    assert len(answers) == 1, "the service did not answer"
    want = "SingleThreadedExecutor" if choice == "single" else "EventsExecutor"
    assert answers[0] == want


def test_make_executor_names(rclpy_context):
    from rclpy.executors import SingleThreadedExecutor
    assert EXECUTORS == ("single", "events")
    assert isinstance(make_executor("single", rclpy_context), SingleThreadedExecutor)
    with pytest.raises(ValueError, match="one of single, events"):
        make_executor("multi", rclpy_context)


def test_constructor_systemexit_propagates_after_cleanup(ros_domain):
    def factory():
        raise SystemExit("node: bad parameter")

    with pytest.raises(SystemExit, match="bad parameter"):
        run_node(factory, [])
    assert not rclpy.ok()


class _SlowToDestroy(Node):
    """A node whose destruction takes 1.3 s (e.g. a driver's shutdown policy on a slow
    bus); it asks to stop itself once up."""

    def __init__(self) -> None:
        super().__init__("slow_to_destroy")
        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGTERM))

    def destroy_node(self) -> None:
        import time
        time.sleep(1.3)
        super().destroy_node()


def test_a_slow_shutdown_says_where_its_time_went(ros_domain, capfd):
    """A clean-up longer than SLOW_SHUTDOWN prints its phases on stderr (a script waiting
    for the node, e.g. run_task.sh, then shows which phase held it); a fast one prints
    nothing (test_named_executor_serves_and_stops_on_signals' nodes)."""
    run_node(_SlowToDestroy, [], robot_description=False)
    err = capfd.readouterr().err
    line = [x for x in err.splitlines() if "shutdown took" in x]
    assert len(line) == 1, err
    assert line[0].startswith("[slow_to_destroy] shutdown took 1.")
    node_s = float(line[0].split("node ")[1].split(" s")[0])
    assert 1.3 <= node_s < 2.0, line[0]
