"""Node tier: ``client.in_executor`` sends action requests from the thread that spins the node.

rclpy 7.1.6 (ros2/rclpy#1123) registers a goal request only after sending it; an executor in
another thread can take the answer first and drop it ("Ignoring unexpected goal response"),
and the goal's future never completes (a CI run lost a gripper goal that way)."""
from __future__ import annotations

import threading
import time

import pytest

from hyperarm_description.qos import DISCOVERY_SETTLE

pytestmark = pytest.mark.node


def test_without_an_executor_start_runs_at_once(rclpy_context):
    import rclpy
    from rclpy.task import Future

    from hyperarm_control.client import in_executor

    node = rclpy.create_node("in_executor_alone", context=rclpy_context)
    try:
        inner = Future()
        calls: list[str] = []

        def start():
            calls.append(threading.current_thread().name)
            return inner

        assert in_executor(node, start) is inner
        assert calls == [threading.current_thread().name]
    finally:
        node.destroy_node()


def test_start_runs_in_the_spinning_thread_and_its_result_is_passed_on(
        rclpy_context, executor, wait_for):
    import rclpy
    from rclpy.task import Future

    from hyperarm_control.client import in_executor

    node = rclpy.create_node("in_executor_thread", context=rclpy_context)
    executor.add_node(node)
    inner = Future()
    threads: list[str] = []

    def start():
        threads.append(threading.current_thread().name)
        return inner

    answer = in_executor(node, start)
    wait_for(lambda: threads, 5.0, what="start called")
    assert threads == ["test-executor"]
    assert not answer.done()
    inner.set_result("accepted")
    wait_for(answer.done, 5.0, what="the result passed on")
    assert answer.result() == "accepted"


def test_many_goals_from_another_thread_are_all_answered(rclpy_context, executor, wait_for):
    """100 goals sent from the test's thread to an in-process server while the executor
    spins in its own: every goal is accepted, every result and cancel answered."""
    import rclpy
    from control_msgs.action import GripperCommand
    from rclpy.action import ActionClient, ActionServer, CancelResponse

    from hyperarm_control.client import in_executor

    server_node = rclpy.create_node("in_executor_server", context=rclpy_context)
    client_node = rclpy.create_node("in_executor_client", context=rclpy_context)

    def execute(handle):
        if handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.succeed()
        result = GripperCommand.Result()
        result.position = handle.request.command.position
        return result

    ActionServer(server_node, GripperCommand, "in_executor_test", execute,
                 cancel_callback=lambda _h: CancelResponse.ACCEPT)
    client = ActionClient(client_node, GripperCommand, "in_executor_test")
    executor.add_node(server_node)
    executor.add_node(client_node)
    wait_for(client.server_is_ready, 10.0, what="the action server")
    time.sleep(DISCOVERY_SETTLE)         # the server also matches the client's readers
    for i in range(100):
        goal = GripperCommand.Goal()
        goal.command.position = float(i)
        sent = in_executor(client_node, lambda g=goal: client.send_goal_async(g))
        wait_for(sent.done, 5.0, what=f"goal {i}'s answer")
        handle = sent.result()
        assert handle.accepted
        if i % 10 == 0:
            cancel = in_executor(client_node, handle.cancel_goal_async)
            wait_for(cancel.done, 5.0, what=f"goal {i}'s cancel answer")
        result = in_executor(client_node, handle.get_result_async)
        wait_for(result.done, 5.0, what=f"goal {i}'s result")
        assert result.result().result.position == float(i)


def test_an_error_of_the_request_reaches_the_caller(rclpy_context, executor, wait_for):
    """start() raising in the spinning thread, or its future failing: the returned future
    carries the exception (before, it would never complete)."""
    import rclpy
    from rclpy.task import Future

    from hyperarm_control.client import in_executor

    node = rclpy.create_node("in_executor_errors", context=rclpy_context)
    executor.add_node(node)

    def refuse():
        raise RuntimeError("no server")

    raised = in_executor(node, refuse)
    wait_for(raised.done, 5.0, what="the raised request's future")
    assert isinstance(raised.exception(), RuntimeError)

    inner = Future()
    failed = in_executor(node, lambda: inner)
    time.sleep(0.1)
    assert not failed.done()
    inner.set_exception(ValueError("bad goal"))
    wait_for(failed.done, 5.0, what="the failed request's future")
    assert isinstance(failed.exception(), ValueError)
