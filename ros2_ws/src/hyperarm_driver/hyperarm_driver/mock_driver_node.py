"""mock_driver: stands in for the robot's drivers, with no hardware.

Publishes ``joint_states`` for every joint of the chosen variant and applies position
setpoints from ``joint_command``. (Foundation version: kinematic joints only.)
"""
from __future__ import annotations

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.joints import JointStateError
from hyperarm_description.model import VARIANTS, DescriptionError, load_description
from hyperarm_description.qos import qos_for

from .mock.joint_sim import JointSim


class MockDriver(Node):
    def __init__(self) -> None:
        super().__init__("mock_driver", namespace=contract.DEFAULT_NAMESPACE)
        self.declare_parameter("variant", "arm", ParameterDescriptor(
            description=f"robot variant: {' or '.join(VARIANTS)}", read_only=True))
        self.declare_parameter("description_file", "", ParameterDescriptor(
            description="robot description YAML ('' = the packaged one)", read_only=True))
        self.declare_parameter("rate", 100.0, ParameterDescriptor(
            description="joint_states publish and simulation rate, Hz", read_only=True))
        variant = self.get_parameter("variant").value
        rate = float(self.get_parameter("rate").value)
        if not 1.0 <= rate <= 1000.0:
            raise SystemExit(f"mock_driver: rate must be within 1..1000 Hz, got {rate}")
        try:
            desc = load_description(self.get_parameter("description_file").value or None, variant)
        except DescriptionError as exc:
            raise SystemExit(f"mock_driver: {exc}") from exc
        self._sim = JointSim(desc)
        self._dt = 1.0 / rate
        self._pub = self.create_publisher(JointState, contract.JOINT_STATES,
                                          qos_for(contract.JOINT_STATES))
        self.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                 qos_for(contract.JOINT_COMMAND))
        self.create_timer(self._dt, self._tick)
        self.get_logger().info(f"mock_driver: {variant}, {len(self._sim.names)} joints at {rate:g} Hz")

    def _on_command(self, msg: JointState) -> None:
        if not msg.position:
            self.get_logger().warn("joint_command without positions ignored (foundation mock)",
                                   throttle_duration_sec=5.0)
            return
        try:
            report = self._sim.command(msg.name, msg.position)
        except JointStateError as exc:
            self.get_logger().error(f"joint_command rejected: {exc}")
            return
        if report.clamped:
            self.get_logger().warn(f"joint_command clamped to limits: {list(report.clamped)}",
                                   throttle_duration_sec=1.0)

    def _tick(self) -> None:
        self._sim.step(self._dt)
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(self._sim.names)
        msg.position = self._sim.position.tolist()
        msg.velocity = self._sim.velocity.tolist()
        msg.effort = [0.0] * len(self._sim.names)
        self._pub.publish(msg)


def main(args: list[str] | None = None) -> None:
    rclpy.init(args=args)
    node = None
    try:
        node = MockDriver()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
