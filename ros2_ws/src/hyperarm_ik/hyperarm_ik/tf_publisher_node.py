"""tf_publisher: the robot's frames on /tf and /tf_static from joint_states (issue 26, TF).

Stands in for robot_state_publisher where apt's is not installed (the PyPI route), from the
same generated URDF through our FK (hyperarm_ik.tf_tree). Publishes every fixed joint once
on /tf_static (one TFMessage, transient local, as tf2_ros' StaticTransformBroadcaster), the
URDF on robot_description (transient local, as robot_state_publisher), and for each
joint_states message the transforms of the moving joints it names on /tf, stamped with the
message's header.stamp (as robot_state_publisher: each driver's joints with their own
stamp). A malformed message (NaN, array lengths, unknown or duplicate names) is rejected
whole; one older than the newest used from the same driver (its joint set), older than
max_state_age, from the future or unstamped is not used. Both are counted in /diagnostics
and logged, throttled per reason.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from hyperarm_description import contract
from hyperarm_description.freshness import REJECT_REASONS, StampGate, stamp_seconds
from hyperarm_description.joints import JointStateError
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import NO_PUB_EVENTS, qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_description.urdf import generate_urdf

from .tf_tree import FrameTransform, TfTree

PARAMETERS: ParamSpec = {
    "max_state_age": (1.0, "s, joint_states stamped longer ago are not used (no /tf from "
                      "them)", Range(0.01, 60.0)),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}
_CACHED_SETS = 16  # joint sets whose TFMessage is kept and refilled (one per driver):
#                   at 100 Hz 14-17 % of a core instead of 20 % rebuilding it (measured)


def _fill(out: TransformStamped, t: FrameTransform) -> None:
    p, q = out.transform.translation, out.transform.rotation
    p.x, p.y, p.z = (float(v) for v in t.translation)
    q.x, q.y, q.z, q.w = (float(v) for v in t.quaternion)


class TfPublisherNode(Node):
    """joint_states -> /tf through :class:`~hyperarm_ik.tf_tree.TfTree`; /tf_static once."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("tf_publisher", **kwargs)
        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        self._tree = TfTree(desc)
        self._gate = StampGate(contract.JOINT_STATES, p["max_state_age"])
        self._throttle = ReasonThrottle(5.0)
        self._counts = {"published": 0, "malformed": 0}
        self._last_problem = ""
        self._messages: dict[tuple[str, ...], TFMessage] = {}  # per joint set, reused
        self._tf = self.create_publisher(TFMessage, contract.TF, qos_for(contract.TF))
        self._static = self.create_publisher(TFMessage, contract.TF_STATIC,
                                             qos_for(contract.TF_STATIC),
                                             event_callbacks=NO_PUB_EVENTS)
        self._urdf = self.create_publisher(String, contract.ROBOT_DESCRIPTION,
                                           qos_for(contract.ROBOT_DESCRIPTION),
                                           event_callbacks=NO_PUB_EVENTS)
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS),
                                           event_callbacks=NO_PUB_EVENTS)
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joint_states,
                                 qos_for(contract.JOINT_STATES))
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self._urdf.publish(String(data=generate_urdf(desc)))
        statics = self._tree.static_transforms()
        self._static.publish(self._message(statics, self.get_clock().now().to_msg()))
        self.get_logger().info(
            f"tf_publisher: {desc.variant} variant, {len(self._tree.frames)} frames from "
            f"{self._tree.root}: {len(statics)} fixed on {contract.TF_STATIC}, "
            f"{len(self._tree.joint_names)} joints on {contract.TF} per {contract.JOINT_STATES}")

    @staticmethod
    def _message(transforms: list[FrameTransform], stamp) -> TFMessage:
        out = TFMessage()
        for t in transforms:
            ts = TransformStamped()
            ts.header.stamp = stamp
            ts.header.frame_id, ts.child_frame_id = t.parent, t.child
            _fill(ts, t)
            out.transforms.append(ts)
        return out

    def _reject(self, reason: str, text: str) -> None:
        self._last_problem = text
        if (line := self._throttle.message(text, reason)):
            self.get_logger().warn(line)

    def _on_joint_states(self, msg: JointState) -> None:
        try:
            positions = self._tree.check(msg.name, msg.position, msg.velocity, msg.effort)
        except JointStateError as exc:
            self._counts["malformed"] += 1
            self._reject("malformed", f"joint_states rejected: {exc}")
            return
        now = self.get_clock().now().nanoseconds * 1e-9
        rejection = self._gate.check(stamp_seconds(msg.header.stamp), now,
                                     source=tuple(msg.name))
        if rejection is not None:
            self._reject(rejection.reason, rejection.text)
            return
        transforms = self._tree.transforms(positions)
        key = tuple(msg.name)
        out = self._messages.get(key)
        if out is None:
            out = self._message(transforms, msg.header.stamp)
            if len(self._messages) < _CACHED_SETS:
                self._messages[key] = out
        else:
            for ts, t in zip(out.transforms, transforms):
                ts.header.stamp = msg.header.stamp
                _fill(ts, t)
        self._tf.publish(out)
        self._counts["published"] += 1

    def _publish_diagnostics(self) -> None:
        counts = {**self._counts, **{r: self._gate.counts[r] for r in REJECT_REASONS}}
        rejected = sum(v for k, v in counts.items() if k != "published")
        level = DiagnosticStatus.WARN if rejected else DiagnosticStatus.OK
        text = (f"{counts['published']} joint_states published on {contract.TF}, "
                f"{rejected} not used" + (f" (last: {self._last_problem})" if rejected else ""))
        values = {**counts, "frames": len(self._tree.frames), "root": self._tree.root}
        st = DiagnosticStatus(level=level, name=f"{self.get_name()}: TF",
                              hardware_id="hyperarm", message=text,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)


def main(args: list[str] | None = None) -> None:
    run_node(TfPublisherNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
