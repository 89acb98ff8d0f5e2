"""task_node: runs named task sequences through the RunTask action.

Streams each stage's joint goals on ``joint_command`` and watches ``joint_states`` until the
stage is reached (see :mod:`hyperarm_tasks.sequences`). One goal at a time: a new goal while
one runs is rejected. Cancel stops the arm where it is (hold: current positions commanded).
"""
from __future__ import annotations

import threading
import time

import rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_interfaces.action import RunTask

from .sequences import StageStatus, TaskError, build_task, stage_status


#: Every parameter of the node (also its --help): name -> (default, description, check).
PARAMETERS: ParamSpec = {
    "command_rate": (50.0, "rate at which stage goals are re-sent on joint_command, Hz",
                     Range(1.0, 500.0)),
}


class TaskNode(Node):
    def __init__(self) -> None:
        super().__init__("task_node", namespace=contract.DEFAULT_NAMESPACE)
        rate = declare_parameters(self, PARAMETERS)["command_rate"]
        self._period = 1.0 / rate
        self._desc = declare_robot_description(self)
        self._cache = JointStateCache()
        self._lock = threading.Lock()
        self._busy = False
        group = ReentrantCallbackGroup()
        self._cmd = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                          qos_for(contract.JOINT_COMMAND))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_states,
                                 qos_for(contract.JOINT_STATES), callback_group=group)
        self._server = ActionServer(
            self, RunTask, contract.RUN_TASK, execute_callback=self._execute,
            goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group)
        self.get_logger().info(f"task_node ready: action {contract.RUN_TASK}")

    def _on_states(self, msg: JointState) -> None:
        try:
            with self._lock:
                self._cache.update(msg.name, msg.position, msg.velocity, msg.effort)
        except JointStateError as exc:
            self.get_logger().warn(f"joint_states ignored: {exc}", throttle_duration_sec=5.0)

    def _on_goal(self, goal: RunTask.Goal) -> GoalResponse:
        with self._lock:
            if self._busy:
                self.get_logger().warn(f"task {goal.task!r} rejected: another task is running")
                return GoalResponse.REJECT
            self._busy = True
        return GoalResponse.ACCEPT

    def _positions(self) -> dict[str, float]:
        with self._lock:
            return dict(self._cache.position)

    def _send(self, goal: dict[str, float]) -> None:
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(goal)
        msg.position = [float(v) for v in goal.values()]
        self._cmd.publish(msg)

    def _execute(self, handle) -> RunTask.Result:
        result = RunTask.Result()
        try:
            return self._run(handle, result)
        finally:
            with self._lock:
                self._busy = False

    def _run(self, handle, result: RunTask.Result) -> RunTask.Result:
        name = handle.request.task
        try:
            stages = build_task(name, self._desc)
        except TaskError as exc:
            result.success, result.message = False, str(exc)
            self.get_logger().error(result.message)
            handle.abort()
            return result
        t_task = time.monotonic()
        self.get_logger().info(f"task {name!r}: {len(stages)} stages")
        for index, stage in enumerate(stages):
            t0 = time.monotonic()
            feedback = RunTask.Feedback(stage=stage.name, stage_index=index,
                                        stage_count=len(stages))
            status = StageStatus.RUNNING
            while status is StageStatus.RUNNING:
                if handle.is_cancel_requested:
                    self._send({n: p for n, p in self._positions().items() if n in stage.goal})
                    handle.canceled()
                    result.success, result.message = False, f"cancelled during {stage.name}"
                    return result
                if not rclpy.ok(context=self.context):
                    result.success, result.message = False, "shutting down"
                    return result
                self._send(dict(stage.goal))
                elapsed = time.monotonic() - t0
                status = stage_status(stage, self._positions(), elapsed)
                feedback.progress = float((index + min(elapsed / stage.timeout, 0.99)) / len(stages))
                handle.publish_feedback(feedback)
                time.sleep(self._period)
            result.stage_names.append(stage.name)
            result.stage_durations.append(time.monotonic() - t0)
            if status is StageStatus.TIMED_OUT:
                missing = [n for n in stage.goal if n not in self._positions()]
                why = (f"no joint_states for {missing}" if missing
                       else "joints did not reach the goal")
                result.success = False
                result.message = f"stage {stage.name!r} timed out after {stage.timeout:g} s ({why})"
                self.get_logger().error(f"task {name!r}: {result.message}")
                handle.abort()
                return result
        result.success, result.message = True, f"task {name!r} done"
        result.total_time = time.monotonic() - t_task
        self.get_logger().info(f"{result.message} in {result.total_time:.2f} s")
        handle.succeed()
        return result


    def destroy_node(self) -> None:
        # The action server first: its pending tasks must not outlive the node's handles.
        self._server.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(TaskNode, args, executor=lambda: MultiThreadedExecutor(num_threads=3),
             parameters=PARAMETERS)


if __name__ == "__main__":
    main()
