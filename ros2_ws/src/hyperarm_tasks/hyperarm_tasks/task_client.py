"""A small client facade for the RunTask action (send, poll, cancel, result).

Modelled on nav2_simple_commander: the caller owns the node and nothing spins in the
background; every call spins the node briefly.

    client = TaskClient(node)
    client.send("ready")
    while not client.done():
        print(client.feedback())
    print(client.result())        # TaskResult.SUCCEEDED / FAILED / CANCELED / REJECTED
"""
from __future__ import annotations

import time
from enum import Enum

import rclpy
from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from rclpy.node import Node

from hyperarm_description import contract
from hyperarm_interfaces.action import RunTask

__all__ = ["TaskResult", "TaskClient"]


class TaskResult(Enum):
    UNKNOWN = 0
    SUCCEEDED = 1
    FAILED = 2
    CANCELED = 3
    REJECTED = 4


class TaskClient:
    def __init__(self, node: Node, action_name: str = contract.RUN_TASK) -> None:
        self._node = node
        self._client = ActionClient(node, RunTask, action_name)
        self._goal_handle = None
        self._result_future = None
        self._feedback: RunTask.Feedback | None = None
        self._unread: list[RunTask.Feedback] = []
        self._state = TaskResult.UNKNOWN
        self.message = ""

    def _spin(self, timeout: float = 0.05) -> None:
        rclpy.spin_once(self._node, timeout_sec=timeout)

    def server_ready(self) -> bool:
        return self._client.server_is_ready()

    def send(self, task: str, timeout: float = 10.0) -> bool:
        """Send a task; False if the server is not there within ``timeout`` s or rejects."""
        if not self._client.wait_for_server(timeout_sec=timeout):
            self.message = f"action server {self._client._action_name!r} not available"
            self._state = TaskResult.REJECTED
            return False
        future = self._client.send_goal_async(RunTask.Goal(task=task),
                                              feedback_callback=self._on_feedback)
        deadline = time.monotonic() + timeout
        while not future.done():
            if time.monotonic() > deadline:
                self.message = "no answer to the goal request"
                self._state = TaskResult.REJECTED
                return False
            self._spin()
        self._goal_handle = future.result()
        if not self._goal_handle.accepted:
            self.message = "goal rejected (is another task running?)"
            self._state = TaskResult.REJECTED
            return False
        self._result_future = self._goal_handle.get_result_async()
        return True

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
        if self._goal_handle is None:
            return
        future = self._goal_handle.cancel_goal_async()
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            self._spin()

    def result(self) -> TaskResult:
        if self._result_future is None or not self._result_future.done():
            return self._state
        wrapped = self._result_future.result()
        self.message = wrapped.result.message
        self._state = {GoalStatus.STATUS_SUCCEEDED: TaskResult.SUCCEEDED,
                       GoalStatus.STATUS_ABORTED: TaskResult.FAILED,
                       GoalStatus.STATUS_CANCELED: TaskResult.CANCELED}.get(
                           wrapped.status, TaskResult.UNKNOWN)
        return self._state

    def result_message(self) -> RunTask.Result | None:
        if self._result_future is None or not self._result_future.done():
            return None
        return self._result_future.result().result
