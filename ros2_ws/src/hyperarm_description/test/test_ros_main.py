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
    # the node's own override slept: rclpy's destroy inside it is told apart, and short
    rclpy_s = float(line[0].split("rclpy's destroy ")[1].split(" s")[0])
    assert rclpy_s < 0.5, line[0]


_DESTROYED: list[str] = []
_BUILT: list[Node] = []     # the nodes the factories below made (destroyed or not)


class _SlowToBuild(Node):
    """A node whose constructor is stopped by a signal half way (after a service and a
    timer, before ``self.ready``): e.g. ik_service building its solvers for seconds."""

    def __init__(self, partial_destroy_fails: bool, inside_rclpy: bool = False) -> None:
        super().__init__("slow_to_build")
        _BUILT.append(self)
        if inside_rclpy:
            # as if the signal landed inside rclpy's Node.__init__, after the rcl node and
            # before its type-description service (a lifecycle run saw exactly that)
            del self._type_description_service
        self.partial_destroy_fails = partial_destroy_fails
        from std_srvs.srv import Trigger
        self.create_service(Trigger, "slow_to_build/ping", lambda _req, res: res)
        self.create_timer(1.0, lambda: None)
        os.kill(os.getpid(), signal.SIGINT)   # the user's Ctrl-C, mid-construction
        import time
        time.sleep(5.0)                       # (interrupted by the signal's exception)
        self.ready = True

    def destroy_node(self) -> None:
        _DESTROYED.append("own")
        if self.partial_destroy_fails:
            assert self.ready                 # an attribute the constructor never set
        super().destroy_node()


@pytest.mark.parametrize("partial_destroy_fails,inside_rclpy",
                         [(False, False), (True, False), (True, True)],
                         ids=["own-destroy", "rclpy-destroy", "rcl-node-only"])
def test_a_signal_during_the_constructor_destroys_the_half_built_node(
        ros_domain, capfd, partial_destroy_fails, inside_rclpy):
    """The node is destroyed before rclpy shuts down: its own destroy_node (its shutdown
    policy) where that works on the partial object, else rclpy's, else the rcl node alone;
    never a traceback. Before, the half-built node was left alive under rclpy's shutdown
    (2.1 s in one lifecycle run)."""
    from rclpy.exceptions import InvalidHandle

    _DESTROYED.clear()
    _BUILT.clear()
    run_node(lambda: _SlowToBuild(partial_destroy_fails, inside_rclpy), [],
             robot_description=False)
    assert _DESTROYED == ["own"]
    assert not rclpy.ok()
    with pytest.raises(InvalidHandle):      # its rcl node was destroyed
        _BUILT[0].get_name()
    err = capfd.readouterr().err
    assert "Traceback" not in err, err
    failed = [line for line in err.splitlines() if "half-built node:" in line]
    assert len(failed) == int(partial_destroy_fails) + int(inside_rclpy), err


class _BadParameter(Node):
    """A node whose constructor ends with a bad parameter's SystemExit after making a
    service (as nodes do through declare_parameters)."""

    def __init__(self) -> None:
        super().__init__("bad_parameter")
        _BUILT.append(self)
        from std_srvs.srv import Trigger
        self.create_service(Trigger, "bad_parameter/ping", lambda _req, res: res)
        raise SystemExit("bad_parameter: bad parameter 'rate': must be > 0")


def test_a_constructor_that_fails_has_its_half_built_node_destroyed(ros_domain):
    """The SystemExit of a bad parameter goes on (exit 1 with its line), and the node the
    constructor had made is destroyed first, not left under rclpy's shutdown."""
    from rclpy.exceptions import InvalidHandle

    _BUILT.clear()
    with pytest.raises(SystemExit, match="must be > 0"):
        run_node(_BadParameter, [], robot_description=False)
    assert not rclpy.ok()
    with pytest.raises(InvalidHandle):
        _BUILT[0].get_name()


def test_a_stuck_shutdown_prints_every_threads_stack(ros_domain, tmp_path):
    """A node process whose clean-up is still running STUCK_SHUTDOWN after the signal
    prints every thread's stack on stderr (where it hangs) and ends with exit code 1, never
    left for a launcher to SIGKILL (Fast DDS' teardown hung for good twice here)."""
    import subprocess
    import sys

    from hyperarm_description.ros_main import STUCK_SHUTDOWN

    script = tmp_path / "stuck.py"
    script.write_text(
        "import os, signal, time\n"
        "from rclpy.node import Node\n"
        "from hyperarm_description.ros_main import run_node\n"
        "class Stuck(Node):\n"
        "    def __init__(self):\n"
        "        super().__init__('stuck')\n"
        "        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGTERM))\n"
        "    def destroy_node(self):\n"
        "        time.sleep(60)  # a teardown that never returns\n"
        "        super().destroy_node()\n"
        "run_node(Stuck, robot_description=False)\n")
    import time
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=50, env=dict(os.environ, ROS_DOMAIN_ID=str(ros_domain)))
    took = time.monotonic() - t0
    assert done.returncode == 1, done.stderr
    assert "Thread 0x" in done.stderr and "in destroy_node" in done.stderr, done.stderr
    assert took < 40.0, took   # the watchdog ended it, not the 60 s sleep
