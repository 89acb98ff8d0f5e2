"""arm_controller: follows joint trajectories on the arm, streaming ``joint_command`` (issue 26).

Takes ``arm_controller/joint_trajectory`` (trajectory_msgs/JointTrajectory), as
joint_trajectory_controller's topic interface does: a new trajectory replaces the running
one, an empty one (no points) stops it and holds. Each control cycle (``rate``) it samples
the trajectory and publishes the command on ``joint_command`` for ``joint1``..``joint9``
(and ``rail`` on rail_arm), while a trajectory runs and until the hold after it is reached;
it is silent otherwise (the drivers hold their last goal). Reads ``joint_states``; publishes
``/diagnostics``. The checks, splines, tolerances and the per-cycle step limit are
:mod:`hyperarm_control.trajectory` (docs/control.md); this node converts messages and wires
them up. (The FollowJointTrajectory action needs control_msgs, which the PyPI route lacks:
not served yet.)
"""
from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from hyperarm_description import contract
from hyperarm_description.freshness import StampGate, stamp_seconds
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node

from .trajectory import (Follower, JointLimits, Tolerances, TrajectoryError,
                         build_trajectory, start_time)

TRAJECTORY_TOPIC = "arm_controller/joint_trajectory"

PARAMETERS: ParamSpec = {
    "rate": (100.0, "Hz, control cycles (one joint_command each while a trajectory runs)",
             Range(1.0, 1000.0)),
    "path_tolerance": (0.1, "rad, default path tolerance of every joint (0 = not checked)",
                       Range(0.0, 10.0)),
    "goal_tolerance": (0.02, "rad, default goal tolerance of every joint (0 = not checked)",
                       Range(0.0, 10.0)),
    "goal_time": (1.0, "s after the trajectory's end to reach the goal tolerance (0 = no "
                  "limit)", Range(0.0, 600.0)),
    "start_tolerance": (0.05, "rad, how far a first point at t = 0 may be from the present "
                        "position", Range(0.0, 1.0)),
    "max_state_age": (0.25, "s, joint_states older than this abort the running trajectory",
                      Range(0.01, 10.0)),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}


def _seconds(duration) -> float:
    return float(duration.sec) + 1e-9 * float(duration.nanosec)


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
        self._follower = Follower(self._limits, self._period, p["max_state_age"])
        self._defaults = Tolerances(np.full(n, p["path_tolerance"]), np.zeros(n),
                                    np.full(n, p["goal_tolerance"]), np.zeros(n),
                                    p["goal_time"])
        self._start_tolerance = p["start_tolerance"]
        self._states = JointStateCache()
        # per driver (its joint set): a message older than the newest used, or than
        # max_state_age, is not used (it would put an old position in the cache)
        self._state_gate = StampGate(contract.JOINT_STATES, p["max_state_age"])
        self._throttle = ReasonThrottle(5.0)
        self._counts = {"accepted": 0, "succeeded": 0, "aborted": 0, "stopped": 0,
                        "rejected": 0, "bad_joint_states": 0}
        self._last_result = "no trajectory yet"
        self._reported = True        # the current goal's end has been logged
        self._active = False         # commanding (a goal runs, or the hold is not reached)
        self._cmd_pub = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                              qos_for(contract.JOINT_COMMAND))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_state,
                                 qos_for(contract.JOINT_STATES))
        self.create_subscription(JointTrajectory, TRAJECTORY_TOPIC, self._on_trajectory, 10)
        self.create_timer(self._period, self._cycle)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.get_logger().info(f"arm_controller: {', '.join(self._names)} at "
                               f"{p['rate']:g} Hz; {TRAJECTORY_TOPIC} -> "
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
        try:
            self._states.update(msg.name, msg.position, msg.velocity, (),
                                stamp_seconds(msg.header.stamp))
        except JointStateError as exc:
            self._counts["bad_joint_states"] += 1
            self._warn(f"joint_states ignored: {exc}", "joint_states")

    def _state(self) -> tuple[np.ndarray, np.ndarray, float]:
        q = self._states.positions(self._names)
        v = np.array([self._states.velocity.get(j, 0.0) for j in self._names])
        stamp = min(self._states.stamp[j] for j in self._names)
        return q, v, stamp

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        if not msg.points:           # joint_trajectory_controller: an empty one stops
            if self._follower.goal_status == "running":
                self._follower.cancel()
                self._counts["stopped"] += 1
                self._last_result = "stopped by an empty trajectory: holding"
                self.get_logger().info(f"arm_controller: {self._last_result}")
            return
        try:
            q, v, _stamp = self._state()
            now = self._now()
            times = [_seconds(pt.time_from_start) for pt in msg.points]
            start, elapsed = start_time(stamp_seconds(msg.header.stamp), max(times), now)
            traj = build_trajectory(
                self._limits, list(msg.joint_names), times,
                [list(pt.positions) for pt in msg.points],
                [list(pt.velocities) for pt in msg.points],
                [list(pt.accelerations) for pt in msg.points],
                start_position=q, start_velocity=v, elapsed=elapsed,
                start_tolerance=self._start_tolerance)
        except (TrajectoryError, JointStateError) as exc:
            self._counts["rejected"] += 1
            code = getattr(exc, "code", None)
            self._last_result = f"rejected ({code}): {exc}" if code else f"rejected: {exc}"
            self._warn(f"arm_controller: trajectory {self._last_result}", type(exc).__name__)
            return
        self._follower.start(traj, self._defaults, start)
        self._counts["accepted"] += 1
        self._active = True
        self._reported = False
        self._last_result = f"running ({traj.kind}, {traj.duration:.2f} s)"

    def _cycle(self) -> None:
        if not self._active:
            return
        try:
            q, v, stamp = self._state()
            cyc = self._follower.step(self._now(), q, stamp, v)
        except (TrajectoryError, JointStateError) as exc:
            self._follower.cancel()
            self._warn(f"arm_controller: {exc}; holding", "cycle")
            return
        msg = JointState(name=self._names, position=[float(x) for x in cyc.command])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._cmd_pub.publish(msg)
        if cyc.status != "running" and not self._reported:
            self._reported = True
            if cyc.status == "succeeded":
                self._counts["succeeded"] += 1
                self._last_result = "succeeded"
                self.get_logger().info("arm_controller: trajectory succeeded")
            elif cyc.status == "aborted":
                self._counts["aborted"] += 1
                self._last_result = f"aborted ({cyc.failure.code}): {cyc.failure}"
                self.get_logger().error(f"arm_controller: trajectory {self._last_result}")
        if cyc.status != "running" and np.array_equal(cyc.command, cyc.desired):
            self._active = False     # the hold is reached: the drivers keep it

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
