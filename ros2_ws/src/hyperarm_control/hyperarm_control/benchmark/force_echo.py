"""force_echo: the floor of force_benchmark's latency figure (not a tool for users).

A node that only copies each joint_states message to joint_command (same names, positions
and stamp): the probe's round trip through it is what two Python processes, DDS and the
executors cost without any control law. ``python -m hyperarm_control.benchmark.force_echo
[single|events] --ros-args ...``
"""
from __future__ import annotations

import sys
from array import array

from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node


class ForceEcho(Node):
    def __init__(self) -> None:
        super().__init__("force_echo", namespace=contract.DEFAULT_NAMESPACE)
        self._out = JointState()
        self._pub = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                          qos_for(contract.JOINT_COMMAND))
        self.create_subscription(JointState, contract.JOINT_STATES, self._echo,
                                 qos_for(contract.JOINT_STATES))

    def _echo(self, msg: JointState) -> None:
        out = self._out
        out.header.stamp = msg.header.stamp
        out.name = msg.name
        out.position = array("d", msg.position)
        self._pub.publish(out)


def main(args: list[str] | None = None) -> None:
    argv = list(sys.argv if args is None else args)
    executor = argv.pop(1) if len(argv) > 1 and not argv[1].startswith("-") else "single"
    run_node(ForceEcho, argv, executor=executor, robot_description=False)


if __name__ == "__main__":
    main()
