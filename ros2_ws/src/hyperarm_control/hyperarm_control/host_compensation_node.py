"""host_compensation: holds tool0 at a pose in the world while the arm's host moves.

Subscribes ``joint_states`` (the rail's too), ``host_pose`` (PoseStamped of base_link in
world) and ``host_compensation/goal`` (PoseStamped of tool0 in world); serves
``host_compensation/enable`` (SetBool: true holds tool0 where it is now); while enabled
publishes arm-only ``joint_command`` on every joint_states message; always publishes
``base_reaction`` (WrenchStamped, the arm's wrench on its mount, base_link) and
diagnostics. The logic is in ``hyperarm_control.host`` (no ROS); docs/host.md.

Inputs: a host_pose or joint state older than the newest one used (per source), or older
than ``max_message_age``, is rejected (``hyperarm_description.freshness.StampGate``); a
malformed one (``hyperarm_control.host.inputs``) too, whole. Each rejection is counted in the
diagnostics and logged, throttled per kind, naming the field.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pinocchio as pin
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from hyperarm_description import contract
from hyperarm_description.freshness import StampGate, stamp_seconds
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import OneOf, ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import EXECUTORS, declare_robot_description, run_node

from hyperarm_ik.errors import IKError
from .host import (MOUNT_POSE_CUTOFF, MOUNT_TWIST_CUTOFF, AccelerationEstimator, CompensationConfig, CompensationLoop, Compensator,
                   DelayEstimator, HostAccelerationEstimator, HostPoseTracker, HostState,
                   LatestWrench, RailHost, ReactionModel)
from .host.inputs import joint_state_problem, pose_problem
from .host.reaction import STANDARD_GRAVITY
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.ros_conversions import pose_to_matrix

_C = CompensationConfig()
PARAMETERS: ParamSpec = {
    "host_source": ("auto", "where the host pose comes from: 'rail' (the rail joint, rail_arm), "
                    "'host_pose' (the topic), 'auto' (rail on rail_arm, else host_pose)",
                    OneOf(("auto", "rail", "host_pose"))),
    "initial_delay": (0.04, "s, the prediction horizon until the loop delay is measured (from "
                      "a command to the joint_states that match it)", Range(0.0, 0.5)),
    "max_horizon": (_C.max_horizon, "s, the prediction horizon's upper bound", Range(0.0, 1.0)),
    "iterations": (_C.iterations, "damped least-squares iterations per cycle", Range(1, 100)),
    "speed_scale": (_C.speed_scale, "fraction of each joint's velocity limit allowed per "
                    "cycle (the step limit)", Range(0.001, 1.0)),
    "limit_margin": (_C.limit_margin, "rad kept from every joint limit", Range(0.0, 0.5)),
    "posture_gain": (_C.posture_gain, "null-space pull back to the posture at enable, per "
                     "cycle", Range(0.0, 1.0)),
    "position_tolerance": (_C.position_tolerance, "m, tool error above which a stalled "
                           "solution is reported unreachable", Range(1e-6, 0.1)),
    "orientation_tolerance": (_C.orientation_tolerance, "rad, likewise for orientation",
                              Range(1e-5, 1.0)),
    "profile_lead": (_C.profile_lead, "lead each joint's command by the distance its servo's "
                     "acceleration-limited profile trails a moving goal, v|v|/(2a)", None),
    "stale_timeout": (0.1, "s without joint_states (or host_pose) before compensation stops "
                      "(latched: enable again)", Range(0.01, 10.0)),
    "reaction_acceleration": ("finite_difference", "joint accelerations in the reaction: "
                              "'finite_difference' of the measured velocities, or 'zero'",
                              OneOf(("finite_difference", "zero"))),
    "reaction_host_acceleration": ("finite_difference", "the host's linear acceleration in "
                                   "the reaction (a fictitious force on the links): "
                                   "'finite_difference' of the host's velocity (host_pose's "
                                   "twist or the rail's), or 'zero'",
                                   OneOf(("finite_difference", "zero"))),
    "contact_wrench_timeout": (0.2, "s: the force node's ee_wrench_base (the wrench the tool "
                               "applies, base_link) enters the reaction while at most this "
                               "old (by arrival); 0 = never", Range(0.0, 10.0)),
    "host_pose_cutoff": (MOUNT_POSE_CUTOFF, "Hz: host_pose's mount-mode filter: the pose "
                         "low-passed at this cutoff, advanced by its time constant at the "
                         "twist low-passed at host_twist_cutoff, so a passive mount's 4-8 Hz "
                         "modes are not fed (docs/host.md); 0 = off", Range(0.0, 100.0)),
    "host_twist_cutoff": (MOUNT_TWIST_CUTOFF, "Hz: the twist's cutoff in that filter (> 0 "
                          "with host_pose_cutoff)", Range(0.0, 100.0)),
    "max_message_age": (0.5, "s: a host_pose or joint_states stamped longer ago than this (by "
                        "the node's clock) is rejected, as is one older than the newest used",
                        Range(0.01, 10.0)),
    "track_position_tolerance": (_C.track_position_tolerance, "m: measured tool error beyond "
                                 "which (3 states in a row) the status is off_track",
                                 Range(1e-5, 1.0)),
    "track_orientation_tolerance": (_C.track_orientation_tolerance, "rad: likewise for "
                                    "orientation", Range(1e-4, 3.0)),
    "diagnostics_period": (1.0, "s between diagnostics", Range(0.05, 60.0)),
    "executor": ("events", "rclpy executor: 'events' (rclpy.experimental.EventsExecutor, the "
                 "least overhead per message) or 'single' (SingleThreadedExecutor)",
                 OneOf(EXECUTORS)),
}


class HostCompensationNode(Node):
    """Thin ROS wrapper around :class:`CompensationLoop` and :class:`ReactionModel`."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("host_compensation", **kwargs)
        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        arm_desc = dataclasses.replace(desc, variant="arm", rail=None)
        source = p["host_source"]
        if source == "auto":
            source = "rail" if desc.rail is not None else "host_pose"
        if source == "rail" and desc.rail is None:
            raise SystemExit("host_compensation: host_source 'rail' needs variant rail_arm")
        try:
            cfg = CompensationConfig(
                iterations=p["iterations"], speed_scale=p["speed_scale"],
                limit_margin=p["limit_margin"], max_horizon=p["max_horizon"],
                position_tolerance=p["position_tolerance"],
                orientation_tolerance=p["orientation_tolerance"],
                posture_gain=p["posture_gain"], profile_lead=p["profile_lead"],
                track_position_tolerance=p["track_position_tolerance"],
                track_orientation_tolerance=p["track_orientation_tolerance"])
            self._loop = CompensationLoop(
                Compensator(Kinematics(arm_desc), cfg),
                DelayEstimator(min(p["initial_delay"], p["max_horizon"])),
                p["stale_timeout"], host_from_states=source == "rail")
            self._reaction = ReactionModel(Kinematics(arm_desc))
        except IKError as exc:
            raise SystemExit(f"host_compensation: {exc}") from exc
        self._source = source
        self._rail = RailHost(desc) if source == "rail" else None
        self._rail_name = desc.rail.name if desc.rail is not None else None
        self._arm = list(arm_desc.arm_joint_names)
        self._arm_set = frozenset(self._arm)
        self._base = desc.base_frame
        self._cache = JointStateCache()
        self._throttle = ReasonThrottle(5.0)
        # unstamped messages (stamp 0) are taken as stamped on arrival, as before
        self._host_gate = StampGate(contract.HOST_POSE, p["max_message_age"],
                                    allow_unstamped=True)
        self._state_gate = StampGate(contract.JOINT_STATES, p["max_message_age"],
                                     allow_unstamped=True)
        self._malformed: dict[str, int] = {}     # "<stream> <kind>" -> messages rejected
        try:
            self._tracker = HostPoseTracker(pose_cutoff=p["host_pose_cutoff"],
                                            twist_cutoff=p["host_twist_cutoff"])
        except IKError as exc:
            raise SystemExit(f"host_compensation: {exc}") from exc
        self._host_time: float | None = None     # arrival (node clock) of the newest host_pose
        self._accel = AccelerationEstimator()
        self._fd = p["reaction_acceleration"] == "finite_difference"
        self._host_accel = HostAccelerationEstimator() \
            if p["reaction_host_acceleration"] == "finite_difference" else None
        self._stale = p["stale_timeout"]
        self._contact = LatestWrench(p["contact_wrench_timeout"])
        self._compute = 0.0
        self._cmd = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                          qos_for(contract.JOINT_COMMAND))
        self._wrench = self.create_publisher(WrenchStamped, contract.BASE_REACTION,
                                             qos_for(contract.BASE_REACTION))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        # the contract's depth: one command per joint_states message, none skipped
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joint_states,
                                 qos_for(contract.JOINT_STATES))
        self.create_subscription(PoseStamped, contract.HOST_POSE, self._on_host_pose,
                                 qos_for(contract.HOST_POSE))
        self.create_subscription(PoseStamped, contract.HOST_COMP_GOAL, self._on_goal,
                                 qos_for(contract.HOST_COMP_GOAL))
        self.create_subscription(WrenchStamped, contract.EE_WRENCH_BASE, self._on_contact_wrench,
                                 qos_for(contract.EE_WRENCH_BASE))
        self.create_service(SetBool, contract.HOST_COMP_ENABLE, self._on_enable)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.create_timer(min(0.05, p["stale_timeout"] / 2.0),
                          lambda: self._log(self._loop.check_stale(self._now())))
        self.get_logger().info(f"host_compensation: {desc.variant}, host from {source}; "
                               f"disabled until {contract.HOST_COMP_ENABLE} true")

    # -- inputs -----------------------------------------------------------------------------
    def _on_host_pose(self, msg: PoseStamped) -> None:
        if self._source != "host_pose":
            return
        pose = self._world_pose(msg, "host_pose ignored", contract.HOST_POSE)
        if pose is None:
            return
        now = self._now()
        stamp = stamp_seconds(msg.header.stamp)
        rejected = self._host_gate.check(stamp, now)
        if rejected is not None:
            self._warn(rejected.text, f"{contract.HOST_POSE} {rejected.reason}")
            return
        try:
            self._tracker.update(stamp or now, pose)
        except IKError as exc:
            self._warn(f"host_pose ignored: {exc}")
            return
        self._host_time = now

    def _on_contact_wrench(self, msg: WrenchStamped) -> None:
        if msg.header.frame_id != self._base:
            self._warn(f"{contract.EE_WRENCH_BASE} ignored: needs frame {self._base!r}, got "
                       f"{msg.header.frame_id!r}")
            return
        f, t = msg.wrench.force, msg.wrench.torque
        try:
            self._contact.update(self._now(), [f.x, f.y, f.z, t.x, t.y, t.z])
        except IKError as exc:
            self._warn(f"{contract.EE_WRENCH_BASE} ignored: {exc}")

    def _on_joint_states(self, msg: JointState) -> None:
        t0 = time.perf_counter()
        problem = joint_state_problem(msg.name, msg.position, msg.velocity, msg.effort,
                                      self._arm_set)
        if problem is not None:
            self._reject_malformed(contract.JOINT_STATES, *problem)
            return
        now = self._now()
        # per source: each driver publishes its own joints with its own stamps
        rejected = self._state_gate.check(stamp_seconds(msg.header.stamp), now,
                                          source=tuple(msg.name))
        if rejected is not None:
            self._warn(rejected.text, f"{contract.JOINT_STATES} {rejected.reason}")
            return
        try:
            self._cache.update(msg.name, msg.position, msg.velocity, msg.effort)
        except JointStateError as exc:
            self._warn(f"joint_states ignored: {exc}")
            return
        c = self._cache
        if not any(n in self._arm_set for n in msg.name) or not c.has(self._arm):
            return
        q = np.array([c.position[n] for n in self._arm])
        host, raw = self._host_state(), self._host_state(raw=True)
        command, log = self._loop.on_state(now, _seconds(msg.header.stamp), q, host,
                                           self._tracker.stamp, self._host_time, raw)
        if command is not None:      # the command first: it is what the loop waits for
            cmd = JointState()
            cmd.header.stamp = msg.header.stamp
            cmd.name = self._arm
            cmd.position = command.tolist()
            self._cmd.publish(cmd)
        self._log(log)
        self._publish_reaction(now, q, raw, msg.header.stamp)
        self._compute = time.perf_counter() - t0

    def _host_state(self, raw: bool = False) -> HostState | None:
        """The host state: for the compensation (host_pose mount-mode filtered) or, with
        ``raw``, as measured (the reaction, the measured tool, the goal at enable)."""
        if self._rail is not None:
            if self._rail_name not in self._cache.position:
                return None
            return self._rail.state(self._cache.position[self._rail_name],
                                    self._cache.velocity.get(self._rail_name, 0.0))
        return self._tracker.raw if raw else self._tracker.state

    def _on_goal(self, msg: PoseStamped) -> None:
        if not self._loop.enabled:
            self._warn(f"{contract.HOST_COMP_GOAL} ignored: not enabled")
            return
        goal = self._world_pose(msg, "goal rejected", contract.HOST_COMP_GOAL)
        if goal is None:
            return
        try:
            self._loop.comp.set_goal(goal)
        except IKError as exc:
            self._warn(f"goal rejected: {exc}")
            return
        self.get_logger().info("new world goal for tool0")

    def _world_pose(self, msg: PoseStamped, what: str, stream: str) -> np.ndarray | None:
        """The message's pose as a 4x4 matrix if it is in world with a finite, unit
        quaternion and a finite position; else None (and a warning of its own kind, naming
        the field, counted per ``stream`` and kind)."""
        o, p = msg.pose.orientation, msg.pose.position
        problem = pose_problem(msg.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w),
                               contract.WORLD_FRAME, what)
        if problem is not None:
            self._reject_malformed(stream, *problem)
            return None
        n = math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w)
        out = pose_to_matrix(msg.pose)
        out[:3, :3] = pin.Quaternion(o.w / n, o.x / n, o.y / n, o.z / n).toRotationMatrix()
        return out

    def _on_enable(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        if not req.data:
            self._log(self._loop.disable("disabled on request"))
            res.success, res.message = True, "disabled"
            return res
        q = (np.array([self._cache.position[n] for n in self._arm])
             if self._cache.has(self._arm) else None)
        ok, message, goal = self._loop.enable(self._now(), q, self._host_state(raw=True),
                                              self._source)
        res.success = ok
        if not ok:
            res.message = message
            self.get_logger().error(message)
            return res
        res.message = (f"holding tool0 at {np.round(goal[:3, 3], 4).tolist()} m in "
                       f"{contract.WORLD_FRAME}")
        self.get_logger().info(res.message)
        return res

    # -- outputs ----------------------------------------------------------------------------
    def _publish_reaction(self, now, q, host: HostState | None, stamp) -> None:
        c = self._cache
        dq = np.array([c.velocity.get(n, 0.0) for n in self._arm])
        # differenced at the states' stamps (arrival only for unstamped states): states
        # that arrive in bursts are still 10 ms of motion apart
        t_state = _seconds(stamp) if _seconds(stamp) > 0.0 else now
        ddq = self._accel.update(t_state, dq) if self._fd else None
        r = host.pose[:3, :3] if host is not None else np.eye(3)
        acc = None
        if self._host_accel is not None and host is not None:
            # differenced at the host state's own stamps, while that state is trusted: the
            # rail's with the joint states, a host_pose fresh and its twist over a baseline
            if self._rail is not None:
                t_host, trusted = _seconds(stamp), _seconds(stamp) > 0.0
            else:
                t_host = self._tracker.stamp
                trusted = self._tracker.twist_full and self._host_time is not None \
                    and now - self._host_time <= self._stale
            a_world = self._host_accel.update(t_host, host.linear) if trusted else None
            if not trusted:
                self._host_accel.reset()
            acc = None if a_world is None else r.T @ a_world
        try:
            w = self._reaction.wrench(q, dq, ddq, gravity_base=r.T @ STANDARD_GRAVITY,
                                      base_acceleration=acc,
                                      contact_wrench_base=self._contact.get(now))
        except IKError as exc:
            self._warn(f"reaction skipped: {exc}")
            return
        msg = WrenchStamped()
        msg.header.stamp = stamp
        msg.header.frame_id = self._base
        f, t = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in w)
        self._wrench.publish(msg)

    def _publish_diagnostics(self) -> None:
        loop = self._loop
        rejected = {f"{g.stream}_rejected_{r}": n for g in (self._host_gate, self._state_gate)
                    for r, n in g.counts.items()}
        malformed = {f"{k.replace(' ', '_rejected_')}": n
                     for k, n in sorted(self._malformed.items())}
        values = dict(loop.diagnostics(), **rejected, **malformed, host_source=self._source,
                      contact_wrench="in use" if self._contact.get(self._now()) is not None
                      else "none",
                      compute_ms=f"{self._compute * 1e3:.3f}")
        st = DiagnosticStatus(level=bytes([1 if loop.status == "unreachable" else 0]),
                              name="host_compensation", hardware_id="host_compensation",
                              message=f"{loop.status}: {loop.reason}",
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)

    def _log(self, lines) -> None:
        for level, text in lines:    # one call site per severity (rclpy's rule)
            if level == "warn":
                self.get_logger().warn(text)
            else:
                self.get_logger().info(text)

    def _reject_malformed(self, stream: str, kind: str, text: str) -> None:
        key = f"{stream} {kind}"
        self._malformed[key] = self._malformed.get(key, 0) + 1
        self._warn(text, key)

    def _warn(self, text: str, reason: str | None = None) -> None:
        if (shown := self._throttle.message(text, reason)):
            self.get_logger().warn(shown)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def main(args: list[str] | None = None) -> None:
    run_node(HostCompensationNode, args, executor="events", parameters=PARAMETERS)


if __name__ == "__main__":
    main()
