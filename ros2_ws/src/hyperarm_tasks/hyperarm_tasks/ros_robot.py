"""The runner's :class:`~hyperarm_tasks.runner.Robot` over ROS topics and services.

Used by the task node (it owns the node; this class only subscribes, publishes, calls and
converts). Everything it reads is cached by the node's executor threads; the runner reads
the caches from the action's execute thread.

- ``joint_states`` -> positions/efforts by name; ``joint_command`` <- streamed goals.
- ``detections`` (camera_link) -> :class:`DetectionBuffer` (root frame).
- Both are judged whole first (:mod:`.inputs`): a malformed, late (older than the
  newest used, or than the documented age) or future-stamped message is not used; each
  rejection is counted (:meth:`RosRobot.input_counts`, the node's diagnostics) and logged,
  throttled per kind.
- ``ee_wrench`` -> wrench; ``hybrid_force/enable`` + ``hybrid_goal`` for force control.
- ``/diagnostics`` -> driver refusals: torque off, a hardware error, the rail not homed.
- ``hold`` (and ``rail/hold``), ``rail/home`` services.
"""
from __future__ import annotations

import functools
import math
import threading
import time
from typing import Mapping, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description.freshness import stamp_seconds
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description import contract
from hyperarm_description.joints import JointStateCache
from hyperarm_description.model import RobotDescription
from hyperarm_description.qos import NO_PUB_EVENTS, NO_SUB_EVENTS, qos_for
from hyperarm_interfaces.msg import Detections, HybridGoal

from .inputs import DetectionFeed, StateFeed
from .perception import DetectionBuffer, camera_pose, matrix_to_quat, quat_to_matrix
from .runner import HybridCommand

WRENCH_IDLE = 2.0   # s without a wrench() call before ee_wrench is unsubscribed

__all__ = ["RosRobot", "pose_to_matrix"]

SERVICE_TIMEOUT = 3.0   # s


def pose_to_matrix(pose) -> np.ndarray:
    out = np.eye(4)
    o = pose.orientation
    out[:3, :3] = quat_to_matrix(o.x, o.y, o.z, o.w)
    out[:3, 3] = (pose.position.x, pose.position.y, pose.position.z)
    return out


class RosRobot:
    """``states_max_age`` / ``detections_max_age``: s, the oldest joint_states / detections
    message used (by the node's clock)."""

    def __init__(self, node: Node, desc: RobotDescription, states_max_age: float = 0.5,
                 detections_max_age: float = 1.0) -> None:
        self.node, self.desc = node, desc
        self._log_throttle = ReasonThrottle(5.0)  # per reason: a new kind is never hidden
        self.detections = DetectionBuffer(camera_pose(desc))
        self.states_feed = StateFeed(states_max_age)
        self.detections_feed = DetectionFeed(desc.camera.frame, detections_max_age)
        self._lock = threading.Lock()
        self._cache = JointStateCache()
        self._wrench: np.ndarray | None = None
        self._wrench_time = 0.0
        self._states_time = -math.inf      # s (node clock), the last joint_states received
        self._diag: dict[str, dict[str, str]] = {}   # joint (or "rail") -> key/values
        # the force node's newest reported mode and reason, and the stamp (s) of that report
        self._force_mode: tuple[float, str, str, str] | None = None
        self._force_enabled_at = math.inf          # s (node clock): our last enable request
        self.goal_handle = None
        # the goal whose cancel the node accepted (task_node's cancel callback): seen here at
        # once, before rclpy moves the goal to CANCELING after the callback returns
        self.cancel_accepted: bytes | None = None
        self.stopping = False    # the node is stopping: the running task stops as cancelled
        self.given: dict[str, np.ndarray] = {}
        group = ReentrantCallbackGroup()
        # no QoS event handlers: they were most of this node's CPU (hyperarm_description.qos)
        sub = functools.partial(node.create_subscription, event_callbacks=NO_SUB_EVENTS)
        pub = functools.partial(node.create_publisher, event_callbacks=NO_PUB_EVENTS)
        sub(JointState, contract.JOINT_STATES, self._on_states, qos_for(contract.JOINT_STATES),
            callback_group=group)
        sub(Detections, contract.DETECTIONS, self._on_detections, qos_for(contract.DETECTIONS),
            callback_group=group)
        # ee_wrench (100 Hz from hybrid_force) only while someone asks for it (wrench()):
        # subscribed all the time it was a third of this node's CPU (issue 28)
        self._sub, self._group = sub, group
        self._wrench_sub = None
        self._wrench_wanted = -math.inf
        sub(DiagnosticArray, contract.DIAGNOSTICS, self._on_diagnostics,
            qos_for(contract.DIAGNOSTICS), callback_group=group)
        self._cmd = pub(JointState, contract.JOINT_COMMAND, qos_for(contract.JOINT_COMMAND))
        self._hybrid = pub(HybridGoal, contract.HYBRID_GOAL, qos_for(contract.HYBRID_GOAL))
        cli = node.create_client
        self._hold = cli(Trigger, contract.HOLD, callback_group=group)
        self._rail_hold = cli(Trigger, contract.RAIL_HOLD, callback_group=group)
        self._rail_home = cli(Trigger, contract.RAIL_HOME, callback_group=group)
        self._force = cli(SetBool, contract.HYBRID_ENABLE, callback_group=group)

    # --- subscriptions (executor threads) ----------------------------------------------
    def _reject(self, problem: tuple[str, str]) -> None:
        reason, text = problem
        if (shown := self._log_throttle.message(text, reason)):
            self.node.get_logger().warn(shown)

    def input_counts(self) -> dict[str, int]:
        """joint_states and detections accepted, and rejected by reason (diagnostics)."""
        with self._lock:
            return {**self.states_feed.counts(), **self.detections_feed.counts()}

    def _on_states(self, msg: JointState) -> None:
        with self._lock:
            problem = self.states_feed.check(msg.name, msg.position, msg.velocity, msg.effort,
                                             stamp_seconds(msg.header.stamp), self.now())
            if problem is None:
                self._cache.update(msg.name, msg.position, msg.velocity, msg.effort)
                self._states_time = self.now()
        if problem is not None:
            self._reject(problem)

    def _on_detections(self, msg: Detections) -> None:
        poses = [((p.position.x, p.position.y, p.position.z),
                  (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w))
                 for p in msg.poses]
        with self._lock:
            problem = self.detections_feed.check(msg.header.frame_id, list(msg.names), poses,
                                                 stamp_seconds(msg.header.stamp), self.now())
        if problem is not None:
            self._reject(problem)
            return
        self.detections.add(stamp_seconds(msg.header.stamp), list(msg.names),
                            [pose_to_matrix(p) for p in msg.poses])

    def _on_wrench(self, msg: WrenchStamped) -> None:
        f, t = msg.wrench.force, msg.wrench.torque
        with self._lock:
            self._wrench = np.array([f.x, f.y, f.z, t.x, t.y, t.z])
            self._wrench_time = time.monotonic()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self._lock:
            for st in msg.status:
                if st.name == "hybrid_force":
                    kv = {k.key: k.value for k in st.values}
                    if self._force_mode is None or stamp >= self._force_mode[0]:
                        self._force_mode = (stamp, kv.get("mode", ""), kv.get("reason", ""),
                                            kv.get("last_event", "").split(":", 1)[0])
                    continue
                joint = st.name.rsplit(": ", 1)[-1]
                if joint in self.desc.all_joint_names or joint == "rail":
                    self._diag[joint] = {kv.key: kv.value for kv in st.values}

    # --- Robot interface (execute thread) --------------------------------------------------
    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def cancel_requested(self) -> bool:
        h = self.goal_handle
        return ((h is not None and (h.is_cancel_requested
                                    or self.cancel_accepted == bytes(h.goal_id.uuid)))
                or self.stopping or not self.node.context.ok())

    def joint_positions(self) -> dict[str, float]:
        with self._lock:
            return dict(self._cache.position)

    def joint_efforts(self) -> dict[str, float]:
        with self._lock:
            return dict(self._cache.effort)

    def joint_states_age(self) -> float:
        with self._lock:
            return self.now() - self._states_time

    def command(self, positions: Mapping[str, float],
                efforts: Mapping[str, float] | None = None) -> None:
        msg = JointState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.name = list(positions)
        msg.position = [float(positions[n]) for n in msg.name]
        if efforts:
            msg.effort = [float(efforts.get(n, 0.0)) for n in msg.name]
        self._cmd.publish(msg)

    def _call(self, client, request, what: str) -> str | None:
        try:
            if not self.node.context.ok():
                return f"{what}: the node is shutting down"
            if not client.wait_for_service(timeout_sec=SERVICE_TIMEOUT):
                return f"{what}: service {client.srv_name} not available"
            future = client.call_async(request)
        except InvalidHandle:     # the node was destroyed under the call (its shutdown)
            return f"{what}: the node is shutting down"
        deadline = time.monotonic() + SERVICE_TIMEOUT
        while not future.done():
            if time.monotonic() > deadline or not self.node.context.ok():
                return f"{what}: no answer from {client.srv_name}"
            time.sleep(0.005)
        res = future.result()
        return None if res.success else f"{what}: {res.message}"

    def hold(self) -> str | None:
        reasons = [self._call(self._hold, Trigger.Request(), "hold")]
        if self.desc.rail and self._rail_hold.service_is_ready():
            reasons.append(self._call(self._rail_hold, Trigger.Request(), "rail/hold"))
        bad = [r for r in reasons if r]
        return "; ".join(bad) if bad else None

    def fault(self, joints: Sequence[str]) -> str | None:
        with self._lock:
            diag = {j: dict(self._diag.get(j, {})) for j in joints}
            rail = dict(self._diag.get("rail", {}))
        for j, kv in diag.items():
            if kv.get("hardware_error", "none") not in ("none", ""):
                return f"{j} is in hardware error ({kv['hardware_error']}): reboot it"
            if kv.get("torque") == "off":
                return f"torque is off on {j}"
        if self.desc.rail and self.desc.rail.name in joints and rail.get("homed") == "false":
            return "the rail is not homed (rail/home first)"
        return None

    def given_object(self, name: str):
        return self.given.get(name)

    def wrench(self):
        """The newest ee_wrench if fresh (0.5 s), else None. The first call subscribes
        (None until the first message); :meth:`drop_idle_inputs` unsubscribes once no call
        came for ``WRENCH_IDLE`` s."""
        with self._lock:
            self._wrench_wanted = time.monotonic()
            if self._wrench_sub is None:
                self._wrench_sub = self._sub(WrenchStamped, contract.EE_WRENCH, self._on_wrench,
                                             qos_for(contract.EE_WRENCH),
                                             callback_group=self._group)
            if self._wrench is None or time.monotonic() - self._wrench_time > 0.5:
                return None
            return self._wrench.copy()

    def drop_idle_inputs(self) -> None:
        """Unsubscribe ee_wrench when :meth:`wrench` was not called for ``WRENCH_IDLE`` s
        (the node's diagnostics timer calls this)."""
        with self._lock:
            sub = self._wrench_sub
            if sub is None or time.monotonic() - self._wrench_wanted < WRENCH_IDLE:
                return
            self._wrench_sub, self._wrench = None, None
        self.node.destroy_subscription(sub)

    def force_available(self) -> bool:
        return self._force.service_is_ready()

    def set_force_control(self, enabled: bool) -> str | None:
        with self._lock:
            self._force_enabled_at = self.now() if enabled else math.inf
        return self._call(self._force, SetBool.Request(data=enabled),
                          "enable force control" if enabled else "disable force control")

    def force_passive(self) -> tuple[str, str] | None:
        """(kind, reason) if the force node reported itself passive after our last enable
        (kind ``stale``: joint states late; ``near_limit``, ``bad_goal``, ...); None while it
        is not known to be."""
        with self._lock:
            m = self._force_mode
            if m is None or m[0] < self._force_enabled_at or m[1] != "passive":
                return None
            return m[3], m[2] or "passive"

    def send_hybrid(self, goal: HybridCommand) -> None:
        msg = HybridGoal()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = self.desc.root_frame
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, goal.xyz)
        q = matrix_to_quat(goal.rotation)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = q
        msg.stiffness = [float(v) for v in goal.stiffness]
        msg.force_controlled = [bool(v) for v in goal.force_axes]
        w = [float(v) for v in goal.wrench]
        msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = w[:3]
        msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = w[3:]
        self._hybrid.publish(msg)

    def home_rail(self) -> str | None:
        return self._call(self._rail_home, Trigger.Request(), "rail/home")

    def rail_homed(self) -> bool | None:
        with self._lock:
            homed = self._diag.get("rail", {}).get("homed")
        return None if homed is None else homed == "true"

    def log(self, level: str, message: str) -> None:
        logger = self.node.get_logger()
        if level == "error":
            logger.error(message)
        elif level == "warn":
            logger.warn(message)
        else:
            logger.info(message)
