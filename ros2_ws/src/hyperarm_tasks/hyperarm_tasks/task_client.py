"""A small client facade for the RunTask action (send, poll, cancel, result).

Modelled on nav2_simple_commander: the caller owns the node and nothing spins in the
background; every call spins the node briefly.

    client = TaskClient(node)
    client.send("ready")
    while not client.done():
        print(client.feedback())
    print(client.result())        # TaskResult.SUCCEEDED / FAILED / CANCELED / REJECTED
    print(client.message)         # the node's message (its reason, for a refused goal)
"""
from __future__ import annotations

import time
from enum import Enum
from typing import Callable

import rclpy
from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from rclpy.node import Node

from hyperarm_description import contract
from hyperarm_description.qos import discovery_settle_left
from hyperarm_interfaces.action import RunTask

__all__ = ["TaskResult", "TaskClient"]


class TaskResult(Enum):
    UNKNOWN = 0
    SUCCEEDED = 1
    FAILED = 2
    CANCELED = 3
    REJECTED = 4


class TaskClient:
    def __init__(self, node: Node, action_name: str = contract.RUN_TASK,
                 spin: Callable[[Node, float], None] | None = None) -> None:
        """``spin(node, timeout)``: how to spin the node once (default rclpy.spin_once);
        run_task passes one that holds off its Ctrl-C exception while rclpy is inside."""
        self._node = node
        self._spin_once = spin or (lambda n, t: rclpy.spin_once(n, timeout_sec=t))
        self._client = ActionClient(node, RunTask, action_name)
        self._created = time.monotonic()
        self._goal_handle = None
        self._send_future = None
        self._result_future = None
        self._feedback: RunTask.Feedback | None = None
        self._unread: list[RunTask.Feedback] = []
        self._state = TaskResult.UNKNOWN
        self.message = ""

    def _spin(self, timeout: float = 0.05) -> None:
        self._spin_once(self._node, timeout)

    def server_ready(self) -> bool:
        return self._client.server_is_ready()

    def send(self, task: str, timeout: float = 10.0) -> bool:
        """Send a task; False if the server is not there within ``timeout`` s or refuses it.

        The task node refuses a goal (another task running) by accepting it and aborting it
        at once with ``failure_kind`` "rejected" and its reason in the result (rclpy's goal
        callback cannot give a reason with a plain rejection): :meth:`result` is then
        ``REJECTED`` and :attr:`message` the node's reason."""
        if not self._client.wait_for_server(timeout_sec=timeout):
            self.message = f"action server {self._client._action_name!r} not available"
            self._state = TaskResult.REJECTED
            return False
        # the server must also have matched this client's response reader
        while discovery_settle_left(self._created, time.monotonic()) > 0.0:
            self._spin(0.02)
        self._send_future = self._client.send_goal_async(RunTask.Goal(task=task),
                                                         feedback_callback=self._on_feedback)
        deadline = time.monotonic() + timeout
        while not self._send_future.done():
            if time.monotonic() > deadline:
                self.message = "no answer to the goal request"
                self._state = TaskResult.REJECTED
                return False
            self._spin()
        return self._take_goal_handle()

    def _take_goal_handle(self) -> bool:
        """The goal handle from the answered send request; False if it was refused."""
        self._goal_handle = self._send_future.result()
        if not self._goal_handle.accepted:
            self.message = "goal rejected by the action server (no reason given)"
            self._state = TaskResult.REJECTED
            return False
        self._result_future = self._goal_handle.get_result_async()
        return True

    def sent(self) -> bool:
        """True once a goal request has gone out (it may still be unanswered)."""
        return self._send_future is not None

    def accepted(self) -> bool | None:
        """None while the goal request is unanswered (or none was sent), else whether the
        action server took the goal."""
        return None if self._goal_handle is None else bool(self._goal_handle.accepted)

    def _on_feedback(self, msg) -> None:
        self._feedback = msg.feedback
        self._unread.append(msg.feedback)
        del self._unread[:-1000]   # bounded if nobody reads them

    def feedback(self) -> RunTask.Feedback | None:
        """The newest feedback."""
        return self._feedback

    def new_feedback(self) -> list[RunTask.Feedback]:
        """Every feedback received since the last call, oldest first."""
        out, self._unread = self._unread, []
        return out

    def done(self) -> bool:
        """Spin once; True when the task has finished (or was never accepted)."""
        if self._result_future is None:
            return True
        self._spin()
        return self._result_future.done()

    def cancel(self, timeout: float = 5.0) -> None:
        """Cancel the goal, waiting up to ``timeout`` s for the server's answer; a goal whose
        request is still unanswered is first awaited (same ``timeout``), then cancelled."""
        deadline = time.monotonic() + timeout
        if self._goal_handle is None and self._send_future is not None:
            while not self._send_future.done() and time.monotonic() < deadline:
                self._spin()
            if not self._send_future.done() or not self._take_goal_handle():
                return
        if self._goal_handle is None or not self._goal_handle.accepted:
            return
        future = self._goal_handle.cancel_goal_async()
        while not future.done() and time.monotonic() < deadline:
            self._spin()

    def result(self) -> TaskResult:
        if self._result_future is None or not self._result_future.done():
            return self._state
        wrapped = self._result_future.result()
        self.message = wrapped.result.message
        if wrapped.result.failure_kind == "rejected":
            self._state = TaskResult.REJECTED
            return self._state
        self._state = {GoalStatus.STATUS_SUCCEEDED: TaskResult.SUCCEEDED,
                       GoalStatus.STATUS_ABORTED: TaskResult.FAILED,
                       GoalStatus.STATUS_CANCELED: TaskResult.CANCELED}.get(
                           wrapped.status, TaskResult.UNKNOWN)
        return self._state

    def result_message(self) -> RunTask.Result | None:
        if self._result_future is None or not self._result_future.done():
            return None
        return self._result_future.result().result
