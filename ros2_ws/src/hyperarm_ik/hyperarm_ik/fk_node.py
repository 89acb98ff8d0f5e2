"""fk_node: publishes the pose of tool0 computed from joint_states (forward kinematics)."""
from __future__ import annotations

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rcl_interfaces.msg import ParameterDescriptor
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.model import VARIANTS, DescriptionError, load_description
from hyperarm_description.qos import qos_for

from .kinematics import Kinematics
from .ros_conversions import matrix_to_pose


class FkNode(Node):
    """Subscribes ``joint_states``; publishes ``tool_pose`` (PoseStamped of tool0)."""

    def __init__(self) -> None:
        super().__init__("fk_node", namespace=contract.DEFAULT_NAMESPACE)
        self.declare_parameter("variant", "arm", ParameterDescriptor(
            description=f"robot variant: {' or '.join(VARIANTS)}", read_only=True))
        self.declare_parameter("description_file", "", ParameterDescriptor(
            description="robot description YAML ('' = the packaged one)", read_only=True))
        variant = self.get_parameter("variant").value
        path = self.get_parameter("description_file").value or None
        try:
            desc = load_description(path, variant)
        except DescriptionError as exc:
            raise SystemExit(f"fk_node: {exc}") from exc
        self._kin = Kinematics(desc)
        self._cache = JointStateCache()
        self._pub = self.create_publisher(PoseStamped, contract.TOOL_POSE,
                                          qos_for(contract.TOOL_POSE))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joint_states,
                                 qos_for(contract.JOINT_STATES))
        self.get_logger().info(
            f"fk_node: {variant} variant, publishing {contract.TOOL_POSE} in {desc.root_frame}")

    def _on_joint_states(self, msg: JointState) -> None:
        try:
            self._cache.update(msg.name, msg.position, msg.velocity, msg.effort)
            q = self._cache.positions(self._kin.joint_names)
        except JointStateError as exc:
            self.get_logger().warn(f"joint_states: {exc}", throttle_duration_sec=5.0)
            return
        out = PoseStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = self._kin.desc.root_frame
        out.pose = matrix_to_pose(self._kin.forward(np.asarray(q)))
        self._pub.publish(out)


def main(args: list[str] | None = None) -> None:
    rclpy.init(args=args)
    node = None
    try:
        node = FkNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
