"""gripper_controller: the gripper's ``control_msgs/GripperCommand`` action (issue 26).

Serves ``gripper_controller/gripper_command`` as ros2_controllers' gripper_action_controller
does: a goal's ``position`` (rad, the gripper joint's own units) and ``max_effort`` (N·m,
the servo's current limit; 0 = the ``max_effort`` parameter, 0 there too = the driver's
default, ``grip_effort``) go to the drivers on ``joint_command`` (position + effort:
current-based position with that limit), each control cycle (``rate``) while the goal runs;
silent otherwise (the drivers hold the last goal). The result and feedback (at
``action_monitor_rate``) report the *measured* position and effort from ``joint_states``,
``reached_goal`` and ``stalled`` (:mod:`hyperarm_control.gripper`). A goal that fails the
checks is accepted and at once aborted (a ROS 2 rejection carries no reason; the reason is
logged and in ``/diagnostics``); a new goal preempts the running one (aborted); a cancel holds
where the gripper is. Stale ``joint_states`` abort the goal.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from control_msgs.action import GripperCommand
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.freshness import StampGate, stamp_seconds
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import action_server_qos, qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node

from .gripper import (GripperError, GripperJudge, GripperLimits, GripperParams,
                      GripperStatus, check_goal)

ACTION = contract.GRIPPER_ACTION

PARAMETERS: ParamSpec = {
    "rate": (50.0, "Hz, control cycles: the state judged and one joint_command while a "
             "goal runs", Range(1.0, 500.0)),
    "action_monitor_rate": (20.0, "Hz, GripperCommand feedback while a goal runs",
                            Range(0.1, 500.0)),
    "goal_tolerance": (0.01, "rad, |measured - goal| at or below this: reached_goal",
                       Range(0.0, 1.0)),
    "stall_velocity_threshold": (0.05, "rad/s, slower than this counts as not moving",
                                 Range(0.0, 10.0)),
    "stall_timeout": (1.0, "s not moving, short of the goal, before it is judged a stall",
                      Range(0.01, 60.0)),
    "allow_stalling": (True, "a stall (closed on an object) succeeds with stalled=true; "
                       "false aborts it, as gripper_action_controller's default", None),
    "max_effort": (0.0, "N·m, the limit of goals with max_effort 0 (0 = the driver's "
                   "default, the description's grip_effort)", Range(0.0, 100.0)),
    "stall_effort_fraction": (0.8, "a stall needs the measured effort towards the goal at "
                              "this fraction of the limit (0 = velocity alone)",
                              Range(0.0, 1.0)),
    "max_state_age": (0.25, "s, joint_states older than this abort the running goal",
                      Range(0.01, 10.0)),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}


@dataclass
class _ActionGoal:
    handle: ServerGoalHandle
    done: Future
    effort_command: float
    next_feedback: float = 0.0


class GripperControllerNode(Node):
    """Thin wrapper around :class:`~hyperarm_control.gripper.GripperJudge`."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__(contract.GRIPPER_CONTROLLER, **kwargs)
        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        self._limits = GripperLimits.from_description(desc)
        self._joint = self._limits.name
        self._params = GripperParams(
            goal_tolerance=p["goal_tolerance"],
            stall_velocity_threshold=p["stall_velocity_threshold"],
            stall_timeout=p["stall_timeout"], allow_stalling=p["allow_stalling"],
            max_effort=p["max_effort"], stall_effort_fraction=p["stall_effort_fraction"],
            max_state_age=p["max_state_age"])
        self._judge = GripperJudge(self._limits, self._params)
        self._gate = StampGate(contract.JOINT_STATES, p["max_state_age"])
        self._throttle = ReasonThrottle(5.0)
        self._state: tuple[float, float, float, float] | None = None  # q, v, effort, stamp
        self._owner: _ActionGoal | None = None
        self._counts = {"accepted": 0, "succeeded": 0, "stalled": 0, "aborted": 0,
                        "canceled": 0, "preempted": 0, "rejected": 0, "bad_joint_states": 0}
        self._last_result = "no goal yet"
        self._last_level = 0
        self._monitor_period = 1.0 / p["action_monitor_rate"]
        self._cmd_pub = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                              qos_for(contract.JOINT_COMMAND))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_state,
                                 qos_for(contract.JOINT_STATES))
        self._server: ActionServer | None = None     # offered once the gripper's state came
        self.create_timer(1.0 / p["rate"], self._cycle)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.get_logger().info(
            f"gripper_controller: {self._joint} [{self._limits.lower:g}, "
            f"{self._limits.upper:.4g}] rad, default limit {self._limits.default_effort:g} "
            f"N·m, at {p['rate']:g} Hz; {ACTION} -> {contract.JOINT_COMMAND}")

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _warn(self, text: str, reason: str) -> None:
        if (line := self._throttle.message(text, reason)):
            self.get_logger().warn(line)

    # -- inputs ---------------------------------------------------------------------------
    def _on_state(self, msg: JointState) -> None:
        if self._joint not in msg.name:
            return
        stamp = stamp_seconds(msg.header.stamp)
        rejection = self._gate.check(stamp, self._now(), source=tuple(msg.name))
        if rejection is not None:
            self._counts["bad_joint_states"] += 1
            self._warn(rejection.text, f"joint_states_{rejection.reason}")
            return
        i = list(msg.name).index(self._joint)
        try:
            q = float(msg.position[i])
            v = float(msg.velocity[i]) if len(msg.velocity) == len(msg.name) else 0.0
            e = float(msg.effort[i]) if len(msg.effort) == len(msg.name) else math.nan
        except IndexError:
            self._counts["bad_joint_states"] += 1
            self._warn(f"joint_states ignored: no position for {self._joint}", "joint_states")
            return
        self._state = (q, v, e, stamp)
        if self._server is None:
            self._server = ActionServer(
                self, GripperCommand, ACTION, execute_callback=self._execute,
                goal_callback=lambda _goal: GoalResponse.ACCEPT,
                cancel_callback=lambda _handle: CancelResponse.ACCEPT, **action_server_qos())
            self.get_logger().info(f"gripper_controller: {self._joint}'s joint_states "
                                   f"received; serving {ACTION}")

    def _measured(self) -> tuple[float, float]:
        return (self._state[0], self._state[2]) if self._state else (math.nan, math.nan)

    # -- the action -----------------------------------------------------------------------
    def _result(self, st: GripperStatus) -> GripperCommand.Result:
        return GripperCommand.Result(position=float(st.position), effort=float(st.effort),
                                     stalled=bool(st.stalled),
                                     reached_goal=bool(st.reached_goal))

    def _command(self, position: float, effort: float) -> None:
        msg = JointState(name=[self._joint], position=[float(position)],
                         effort=[float(effort)])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._cmd_pub.publish(msg)

    async def _execute(self, handle: ServerGoalHandle) -> GripperCommand.Result:
        cmd = handle.request.command
        q, e = self._measured()
        try:
            goal = check_goal(cmd.position, cmd.max_effort, self._limits, self._params)
        except GripperError as exc:
            self._counts["rejected"] += 1
            self._last_result, self._last_level = f"rejected: {exc}", 1
            self.get_logger().error(f"gripper_controller: goal aborted: {exc}; nothing sent")
            handle.abort()
            return self._result(GripperStatus("aborted", q, e, reason=str(exc)))
        if goal.clamped:
            self._warn(f"gripper_controller: max_effort {cmd.max_effort:g} N·m above the "
                       f"servo's {self._limits.stall_effort:g} N·m: clamped", "clamped")
        if self._judge.start(goal, self._now()):
            self._counts["preempted"] += 1
            self.get_logger().info("gripper_controller: goal preempted by a new goal")
            self._end(GripperStatus("aborted", q, e, reason="preempted by a new goal"))
        self._counts["accepted"] += 1
        self._last_result, self._last_level = (
            f"running: to {goal.position:.4f} rad, limit {goal.limit:.3g} N·m", 0)
        self._owner = _ActionGoal(handle, Future(), goal.effort_command)
        self._command(goal.position, goal.effort_command)
        return await self._owner.done

    def _end(self, st: GripperStatus) -> None:
        owner, self._owner = self._owner, None
        if owner is None or not owner.handle.is_active:
            return
        if st.status == "canceled":
            owner.handle.canceled()
        elif st.status == "succeeded":
            owner.handle.succeed()
        else:
            owner.handle.abort()
        owner.done.set_result(self._result(st))

    def before_shutdown(self) -> bool:
        """On SIGINT/SIGTERM (run_node): a running goal is aborted, saying so, so that its
        client gets a result (True: run_node then spins to send it); the driver keeps the
        last goal."""
        if not (self._owner is not None and self._judge.running):
            return False
        q, e = self._measured()
        st = self._judge.cancel(q, e)
        self._end(GripperStatus("aborted", st.position, st.effort, reason=(
            "gripper_controller shutting down: goal aborted, the gripper keeps its last "
            "goal")))
        return True

    def _finish(self, st: GripperStatus) -> None:
        """Count, log and report a goal that ended in the judge."""
        if st.status == "succeeded":
            self._counts["stalled" if st.stalled else "succeeded"] += 1
            self._last_result, self._last_level = f"succeeded: {st.reason}", 0
            self.get_logger().info(f"gripper_controller: {st.reason}")
        elif st.status == "canceled":
            self._counts["canceled"] += 1
            self._last_result, self._last_level = st.reason, 0
            self.get_logger().info(f"gripper_controller: {st.reason}")
        else:
            self._counts["aborted"] += 1
            self._last_result, self._last_level = f"aborted: {st.reason}", 2
            self.get_logger().error(f"gripper_controller: goal aborted: {st.reason}")
        self._end(st)

    def _cycle(self) -> None:
        owner = self._owner
        if owner is None or not self._judge.running:
            return
        q, v, e, stamp = self._state
        if owner.handle.is_cancel_requested:
            st = self._judge.cancel(q, e)
            self._command(q, owner.effort_command)        # hold where it is, once
            self._finish(st)
            return
        st = self._judge.step(self._now(), q, v, e, stamp)
        if st.done:
            self._finish(st)
            return
        self._command(self._judge.goal.position, owner.effort_command)
        now = self._now()
        if now >= owner.next_feedback:
            owner.next_feedback = now + self._monitor_period
            owner.handle.publish_feedback(GripperCommand.Feedback(
                position=float(st.position), effort=float(st.effort), stalled=False,
                reached_goal=False))

    def _publish_diagnostics(self) -> None:
        q, e = self._measured()
        values = {**self._counts, "commanding": str(self._judge.running).lower(),
                  "position": f"{q:.4f}", "effort": f"{e:.3f}",
                  "last_result": self._last_result}
        st = DiagnosticStatus(level=bytes([self._last_level]), name="gripper_controller",
                              hardware_id=self._joint, message=self._last_result,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)


def main(args: list[str] | None = None) -> None:
    run_node(GripperControllerNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
