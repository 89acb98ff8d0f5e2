"""arm_controller: follows joint trajectories on the arm, streaming ``joint_command`` (issue 26).

Serves ``arm_controller/follow_joint_trajectory`` (control_msgs/FollowJointTrajectory) and
takes ``arm_controller/joint_trajectory`` (trajectory_msgs/JointTrajectory), as
joint_trajectory_controller does: a new goal or trajectory replaces the running one (a
preempted action goal is aborted, saying so), a cancel or an empty trajectory stops and
holds. A goal that fails the checks is accepted and at once aborted with the action's error
code and a message (a ROS 2 rejection carries no reason); it does not disturb a running one.
Each control cycle (``rate``) it samples the trajectory and publishes the command on
``joint_command`` for ``joint1``..``joint9`` (and ``rail`` on rail_arm), while a trajectory
runs and until the hold after it is reached; it is silent otherwise (the drivers hold their
last goal). Action feedback (desired, actual, error) at ``action_monitor_rate``. Reads
``joint_states``; publishes ``/diagnostics``. The checks, splines, tolerances and the
per-cycle step limit are :mod:`hyperarm_control.trajectory` (docs/control.md); this node
converts messages (:mod:`hyperarm_control.messages`) and wires them up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from control_msgs.action import FollowJointTrajectory
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from hyperarm_description import contract
from hyperarm_description.freshness import StampGate, stamp_seconds
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import action_server_qos, qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node

from .messages import TrajectoryArgs, feedback, goal_tolerances, trajectory_args
from .trajectory import (SUCCESSFUL, CommanderWatch, Follower, InvalidGoal, JointLimits,
                         StateCheck, Tolerances, TrajectoryError, build_trajectory,
                         start_time)

TRAJECTORY_TOPIC = contract.ARM_TRAJECTORY_TOPIC
ACTION = contract.ARM_TRAJECTORY_ACTION

PARAMETERS: ParamSpec = {
    "rate": (100.0, "Hz, control cycles (one joint_command each while a trajectory runs); "
             "with cycle_on_joint_states, set it to the arm driver's rate",
             Range(1.0, 1000.0)),
    "cycle_on_joint_states": (True, "run each control cycle when the arm driver's "
                              "joint_states arrive (read, update, write, as ros2_control "
                              "does), so every command reaches the driver the same time "
                              "before its next cycle; the rate timer then only runs a cycle "
                              "when joint_states are 2.5 periods late", None),
    "path_tolerance": (0.1, "rad, default path tolerance of every joint (0 = not checked)",
                       Range(0.0, 10.0)),
    "goal_tolerance": (0.02, "rad, default goal tolerance of every joint (0 = not checked)",
                       Range(0.0, 10.0)),
    "goal_time": (1.0, "s after the trajectory's end to reach the goal tolerance (0 = no "
                  "limit)", Range(0.0, 600.0)),
    "start_tolerance": (0.05, "rad, how far a first point at t = 0 may be from the present "
                        "position", Range(0.0, 1.0)),
    "command_lead": (0.02, "s, commands are the trajectory this far ahead of the cycle's "
                     "time, making up for the servos' delay in reaching a goal position "
                     "(docs/control.md); 0 sends the present point", Range(0.0, 0.5)),
    "profile_lead": (True, "add v|v|/(2a) to each command: the distance the servos' "
                     "acceleration-limited profile (Profile Acceleration = the description's "
                     "limit, as dynamixel_driver writes it) trails a moving goal", None),
    "handover_quiet": (0.5, "s: a goal is refused while another node was heard on "
                       "joint_command naming these joints less than this ago, and a running "
                       "goal stops when one is heard (one commander at a time, "
                       "docs/architecture.md); 0 = no check", Range(0.0, 10.0)),
    "max_state_age": (0.25, "s, joint_states older than this abort the running trajectory",
                      Range(0.01, 10.0)),
    "action_monitor_rate": (20.0, "Hz, FollowJointTrajectory feedback while a goal runs",
                            Range(0.1, 1000.0)),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}


@dataclass
class _ActionGoal:
    """The action goal that owns the follower's goal; ``done`` carries its result."""

    handle: ServerGoalHandle
    done: Future
    next_feedback: float = 0.0


class ArmControllerNode(Node):
    """Thin wrapper around :class:`~hyperarm_control.trajectory.Follower`."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("arm_controller", **kwargs)
        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        self._limits = JointLimits.from_description(desc)
        self._names = list(self._limits.names)
        n = len(self._names)
        self._period = 1.0 / p["rate"]
        self._on_states = p["cycle_on_joint_states"]
        self._last_cycle = -math.inf     # node-clock time of the last control cycle, s
        self._last_timer = math.inf      # node-clock time of the last rate timer tick, s
        self._follower = Follower(self._limits, self._period, p["max_state_age"],
                                  p["command_lead"],
                                  self._limits.acceleration if p["profile_lead"] else None)
        self._defaults = Tolerances(np.full(n, p["path_tolerance"]), np.zeros(n),
                                    np.full(n, p["goal_tolerance"]), np.zeros(n),
                                    p["goal_time"])
        self._start_tolerance = p["start_tolerance"]
        self._watch = CommanderWatch(self._names, p["handover_quiet"])
        self._last_sent = -math.inf      # node-clock time of the last joint_command sent, s
        self._states = JointStateCache()
        # per driver (its joint set): a message older than the newest used, or than
        # max_state_age, is not used (it would put an old position in the cache)
        # (0.1 s into the future at most: a state from the future would make the real ones
        # "out of order"); then per joint: finite, in order, no faster than its limit
        self._state_gate = StampGate(contract.JOINT_STATES, p["max_state_age"],
                                     max_future=0.1)
        self._state_check = StateCheck(self._names, self._limits.velocity)
        self._throttle = ReasonThrottle(5.0)
        self._counts = {"accepted": 0, "succeeded": 0, "aborted": 0, "stopped": 0,
                        "rejected": 0, "bad_joint_states": 0, "yielded": 0}
        self._last_result = "no trajectory yet"
        self._reported = True        # the current goal's end has been logged
        self._active = False         # commanding (a goal runs, or the hold is not reached)
        self._owner: _ActionGoal | None = None   # the action goal being followed
        self._monitor_period = 1.0 / p["action_monitor_rate"]
        self._cmd_pub = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                              qos_for(contract.JOINT_COMMAND))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_state,
                                 qos_for(contract.JOINT_STATES))
        self.create_subscription(JointTrajectory, TRAJECTORY_TOPIC, self._on_trajectory, 10)
        # the other commanders (one at a time; and where they left the arm)
        self.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                 qos_for(contract.JOINT_COMMAND))
        # offered once joint_states of every joint have arrived (see _on_state): a client
        # waiting for the server (MoveIt does) then never sends a goal it must refuse
        self._server: ActionServer | None = None
        self.create_timer(self._period, self._on_timer)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.get_logger().info(f"arm_controller: {', '.join(self._names)} at "
                               f"{p['rate']:g} Hz; {ACTION}, {TRAJECTORY_TOPIC} -> "
                               f"{contract.JOINT_COMMAND}")

    def _warn(self, text: str, reason: str) -> None:
        if (line := self._throttle.message(text, reason)):
            self.get_logger().warn(line)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_state(self, msg: JointState) -> None:
        rejection = self._state_gate.check(stamp_seconds(msg.header.stamp), self._now(),
                                           source=tuple(msg.name))
        if rejection is not None:
            self._counts["bad_joint_states"] += 1
            self._warn(rejection.text, f"joint_states_{rejection.reason}")
            return
        why = self._state_check.check(msg.name, msg.position, msg.velocity,
                                      stamp_seconds(msg.header.stamp))
        if why is not None:
            self._counts["bad_joint_states"] += 1
            self._warn(f"joint_states ignored: {why}", "joint_states_implausible")
            return
        try:
            self._states.update(msg.name, msg.position, msg.velocity, (),
                                stamp_seconds(msg.header.stamp))
        except JointStateError as exc:
            self._counts["bad_joint_states"] += 1
            self._warn(f"joint_states ignored: {exc}", "joint_states")
            return
        # the arm driver's message (a rail's comes from another driver): cycle now, unless
        # the last cycle was less than 3/4 of a period ago (a faster driver, a burst)
        if (self._on_states and self._active and self._names[-1] in msg.name
                and self._now() - self._last_cycle >= 0.75 * self._period):
            self._cycle()
        if self._server is None and all(j in self._states.stamp for j in self._names):
            self._server = ActionServer(self, FollowJointTrajectory, ACTION,
                                        execute_callback=self._execute,
                                        goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                        cancel_callback=lambda _handle: CancelResponse.ACCEPT,
                                        **action_server_qos())
            self.get_logger().info(f"arm_controller: joint_states of every joint received; "
                                   f"serving {ACTION}")

    def _state(self) -> tuple[np.ndarray, np.ndarray, float]:
        q = self._states.positions(self._names)
        v = np.array([self._states.velocity.get(j, 0.0) for j in self._names])
        stamp = min(self._states.stamp[j] for j in self._names)
        return q, v, stamp

    def _start(self, args: TrajectoryArgs, goal=None) -> None:
        """Check a goal and start following it (preempting the running one); raises
        TrajectoryError or JointStateError, with nothing changed, when it fails a check."""
        if (busy := self._watch.busy(self._now())) is not None:
            raise InvalidGoal(busy)
        q, v, _stamp = self._state()
        start, elapsed = start_time(args.stamp, args.duration, self._now())
        reseed = False
        if not self._active:         # the arm may have been moved by another commander
            last = self._follower.last_command
            reseed = (last is not None and (
                self._watch.last_other > self._last_sent
                or float(np.max(np.abs(q - last))) > self._start_tolerance))
        traj = build_trajectory(
            self._limits, args.joint_names, args.times, args.positions, args.velocities,
            args.accelerations, start_position=q, start_velocity=v, elapsed=elapsed,
            start_tolerance=self._start_tolerance)
        tol = self._defaults if goal is None else goal_tolerances(goal, self._names,
                                                                  self._defaults)
        self._end_action(FollowJointTrajectory.Result.INVALID_GOAL,
                         "preempted by a new goal" if goal is not None else
                         f"preempted by a trajectory on {TRAJECTORY_TOPIC}", abort=True)
        if reseed:
            self._follower.reseed(q)
        self._follower.start(traj, tol, start)
        self._counts["accepted"] += 1
        self._active = True
        self._reported = False
        self._last_result = f"running ({traj.kind}, {traj.duration:.2f} s)"

    def _on_command(self, msg: JointState) -> None:
        if not self._watch.observe(msg.name, msg.position, self._now()):
            return
        if not self._active or self._watch.quiet <= 0.0:
            return
        # another commander while this one streams: stop at once, sending nothing more
        running = self._follower.goal_status == "running"
        self._follower.cancel()
        self._follower.release()
        self._active = False
        self._counts["yielded"] += 1
        text = (f"another node commanded {', '.join(self._watch.other_joints)} on "
                f"joint_command: {'goal aborted, ' if running else ''}arm_controller "
                "stopped commanding (one commander at a time)")
        self._last_result = f"aborted (-1): {text}" if running else self._last_result
        self._reported = True
        self._end_action(FollowJointTrajectory.Result.INVALID_GOAL, text, abort=True)
        self._warn(f"arm_controller: {text}", "yielded")

    def _rejected(self, exc: Exception) -> tuple[int, str]:
        self._counts["rejected"] += 1
        code = getattr(exc, "code", FollowJointTrajectory.Result.INVALID_GOAL)
        self._last_result = f"rejected ({code}): {exc}"
        self._warn(f"arm_controller: trajectory {self._last_result}", type(exc).__name__)
        return code, str(exc)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        if not msg.points:           # joint_trajectory_controller: an empty one stops
            if self._follower.goal_status == "running":
                self._follower.cancel()
                self._end_action(FollowJointTrajectory.Result.INVALID_GOAL,
                                 f"stopped by an empty trajectory on {TRAJECTORY_TOPIC}",
                                 abort=True)
                self._counts["stopped"] += 1
                self._last_result = "stopped by an empty trajectory: holding"
                self.get_logger().info(f"arm_controller: {self._last_result}")
            return
        try:
            self._start(trajectory_args(msg))
        except (TrajectoryError, JointStateError) as exc:
            self._rejected(exc)

    async def _execute(self, handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        try:
            self._start(trajectory_args(handle.request.trajectory), handle.request)
        except (TrajectoryError, JointStateError) as exc:
            code, text = self._rejected(exc)
            handle.abort()
            return FollowJointTrajectory.Result(error_code=code, error_string=text)
        self._owner = _ActionGoal(handle, Future())
        return await self._owner.done

    def _end_action(self, code: int, text: str, *, abort: bool = False,
                    cancelled: bool = False) -> None:
        """End the action goal being followed (if any) with ``code`` and ``text``."""
        owner, self._owner = self._owner, None
        if owner is None or not owner.handle.is_active:
            return
        if cancelled:
            owner.handle.canceled()
        elif abort:
            owner.handle.abort()
        else:
            owner.handle.succeed()
        owner.done.set_result(FollowJointTrajectory.Result(error_code=code, error_string=text))

    def before_shutdown(self) -> bool:
        """On SIGINT/SIGTERM (run_node): a running goal is aborted, saying so, so that its
        client gets a result (True: run_node then spins to send it); the drivers keep the
        last command (the arm holds)."""
        if not (self._owner is not None or self._follower.goal_status == "running"):
            return False
        self._follower.cancel()
        self._active = False
        self._last_result = "aborted (-1): arm_controller shutting down"
        self._end_action(FollowJointTrajectory.Result.INVALID_GOAL,
                         "arm_controller shutting down: goal aborted, the arm holds its last "
                         "command", abort=True)
        return True

    def _monitor_action(self, cyc) -> None:
        owner = self._owner
        if owner is None:
            return
        if owner.handle.is_cancel_requested and cyc.status == "running":
            self._follower.cancel()
            self._counts["stopped"] += 1
            self._last_result = "cancelled: holding"
            self.get_logger().info("arm_controller: goal cancelled, holding")
            self._end_action(SUCCESSFUL, "cancelled: holding", cancelled=True)
        elif cyc.status == "running" and self._now() >= owner.next_feedback:
            owner.next_feedback = self._now() + self._monitor_period
            owner.handle.publish_feedback(feedback(
                FollowJointTrajectory.Feedback, cyc, self._names,
                self.get_clock().now().to_msg()))

    def _on_timer(self) -> None:
        now = self._now()
        late, self._last_timer = now - self._last_timer > 2.0 * self._period, now
        if late:
            # this node was not scheduled for a while (a loaded machine): the executor runs
            # the timer before the joint_states that queued meanwhile, so the state would
            # look stale; the next tick, after them, judges it
            return
        if (self._on_states
                and now - self._last_cycle < 2.5 * self._period):
            return                   # joint_states drive the cycles
        self._cycle()

    def _cycle(self) -> None:
        if not self._active:
            return
        self._last_cycle = self._now()
        try:
            q, v, stamp = self._state()
            now = self.get_clock().now()
            cyc = self._follower.step(now.nanoseconds * 1e-9, q, stamp, v)
        except (TrajectoryError, JointStateError) as exc:
            self._follower.cancel()
            self._end_action(getattr(exc, "code", FollowJointTrajectory.Result.INVALID_GOAL),
                             f"{exc}; holding", abort=True)
            self._warn(f"arm_controller: {exc}; holding", "cycle")
            return
        msg = JointState(name=self._names, position=[float(x) for x in cyc.command])
        msg.header.stamp = now.to_msg()      # the instant the trajectory was sampled
        self._watch.sent(msg.position)
        self._last_sent = self._now()
        self._cmd_pub.publish(msg)
        self._monitor_action(cyc)
        if cyc.status != "running" and not self._reported:
            self._reported = True
            if cyc.status == "succeeded":
                self._counts["succeeded"] += 1
                self._last_result = "succeeded"
                self.get_logger().info("arm_controller: trajectory succeeded")
                self._end_action(SUCCESSFUL, "")
            elif cyc.status == "aborted":
                self._counts["aborted"] += 1
                self._last_result = f"aborted ({cyc.failure.code}): {cyc.failure}"
                self.get_logger().error(f"arm_controller: trajectory {self._last_result}")
                self._end_action(cyc.failure.code, str(cyc.failure), abort=True)
        if cyc.status != "running" and np.array_equal(cyc.command, cyc.desired):
            self._active = False     # the hold is reached: the drivers keep it
            self._follower.release()

    def _publish_diagnostics(self) -> None:
        level = 2 if self._last_result.startswith("aborted") else (
            1 if self._last_result.startswith("rejected") else 0)
        values = {**self._counts, "status": self._follower.goal_status,
                  "commanding": str(self._active).lower(), "last_result": self._last_result}
        st = DiagnosticStatus(level=bytes([level]), name="arm_controller",
                              hardware_id="arm", message=self._last_result,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)


def main(args: list[str] | None = None) -> None:
    run_node(ArmControllerNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
