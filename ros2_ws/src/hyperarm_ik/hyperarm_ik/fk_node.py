"""fk_node: publishes the pose of tool0 computed from joint_states (forward kinematics)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node

from .errors import IKError
from .kinematics import Kinematics
from .ros_conversions import matrix_to_pose


class FkNode(Node):
    """Subscribes ``joint_states``; publishes ``tool_pose`` (PoseStamped of tool0)."""

    def __init__(self) -> None:
        super().__init__("fk_node", namespace=contract.DEFAULT_NAMESPACE)
        desc = declare_robot_description(self)
        variant = desc.variant
        self._kin = Kinematics(desc)
        self._cache = JointStateCache()
        self._throttle = ReasonThrottle(5.0)  # per reason: a new kind of error is never hidden
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
            if (text := self._throttle.message(f"joint_states: {exc}")):
                self.get_logger().warn(text)
            return
        try:
            pose = matrix_to_pose(self._kin.forward(np.asarray(q)))
        except IKError as exc:
            if (text := self._throttle.message(f"forward kinematics: {exc}")):
                self.get_logger().error(text)
            return
        out = PoseStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = self._kin.desc.root_frame
        out.pose = pose
        self._pub.publish(out)


def main(args: list[str] | None = None) -> None:
    run_node(FkNode, args)


if __name__ == "__main__":
    main()
