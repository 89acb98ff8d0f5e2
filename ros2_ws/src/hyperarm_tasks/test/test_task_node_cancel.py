"""The task node in-process (issue 24, item 2): a cancel the node has accepted is seen by the
task's thread at once. rclpy moves the goal to CANCELING only after the cancel callback has
returned; in that window (after the "cancel requested" line) the task thread used to see no
cancel and started its first step (one `make test` run: `step 1/12` logged after the cancel
of a Ctrl-C that came as the goal was accepted). Two goals in a row: the first's cancel
does not carry over to the second, whose own cancel is seen the same way."""
from __future__ import annotations

import pytest

pytestmark = [pytest.mark.node]


def test_an_accepted_cancel_is_seen_before_rclpy_moves_the_goal(rclpy_context, executor,
                                                                 wait_for, monkeypatch):
    import rclpy
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient

    from hyperarm_description import contract
    from hyperarm_interfaces.action import RunTask
    from hyperarm_tasks.task_node import TaskNode

    from hyperarm_tasks import runner

    # the task waits for joint_states (none come) long enough for any load
    monkeypatch.setattr(runner, "STATE_WAIT", 60.0)
    node = TaskNode(context=rclpy_context)
    seen = []

    def on_cancel(handle):
        answer = node._on_cancel(handle)
        # what the task thread sees the moment the callback has answered: the goal is not
        # CANCELING yet, the cancel must be seen all the same
        seen.append((handle.is_cancel_requested, node._robot.cancel_requested()))
        return answer

    node._server.register_cancel_callback(on_cancel)
    client_node = rclpy.create_node("cancel_probe", context=rclpy_context)
    client = ActionClient(client_node, RunTask, f"{contract.DEFAULT_NAMESPACE}/"
                          f"{contract.RUN_TASK}".replace("//", "/"))
    executor.add_node(node)
    executor.add_node(client_node)
    try:
        assert client.wait_for_server(timeout_sec=10.0)
        # no driver runs: the task waits for joint_states before its first step
        send = client.send_goal_async(RunTask.Goal(task="block_transfer"))
        wait_for(send.done, 10.0, what="the goal's answer")
        handle = send.result()
        assert handle.accepted
        wait_for(lambda: node._robot.goal_handle is not None, 10.0,
                 what="the task loaded (its goal handed to the robot)")
        cancel = handle.cancel_goal_async()
        wait_for(cancel.done, 10.0, what="the cancel's answer")
        assert cancel.result().goals_canceling, "the cancel was refused"
        # seen[0][0]: rclpy has not moved the goal yet (the window); [1]: the task sees it
        assert seen and seen[0][1], \
            f"(goal CANCELING, cancel seen by the task) at the callback's answer: {seen}"
        result = handle.get_result_async()
        wait_for(result.done, 10.0, what="the result")
        res = result.result()
        assert res.status == GoalStatus.STATUS_CANCELED, f"status {res.status}, not CANCELED: {res.result.message}"
        assert not res.result.success and res.result.failure_kind == "cancelled"
        assert "cancelled before" in res.result.message, res.result.message
        # the next goal (in sequence) is not taken for cancelled: it waits for joint_states
        # until its own cancel, which is seen as the first one was
        assert node._robot.cancel_accepted is None        # cleared with its goal
        wait_for(lambda: node._busy is None, 5.0, what="the slot free")
        send = client.send_goal_async(RunTask.Goal(task="block_transfer"))
        wait_for(send.done, 10.0, what="the second goal's answer")
        second = send.result()
        assert second.accepted
        wait_for(lambda: node._robot.goal_handle is not None, 10.0, what="the second task")
        assert not node._robot.cancel_requested(), "the second goal taken for cancelled"
        seen.clear()
        cancel = second.cancel_goal_async()
        wait_for(cancel.done, 10.0, what="the second cancel's answer")
        assert seen and seen[0][1], seen
        result = second.get_result_async()
        wait_for(result.done, 10.0, what="the second result")
        assert result.result().status == GoalStatus.STATUS_CANCELED
    finally:
        executor.remove_node(client_node)
        client.destroy()
        client_node.destroy_node()
        executor.remove_node(node)
        node.destroy_node()
