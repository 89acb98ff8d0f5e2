"""Node tier: host_compensation in-process on the fixed arm with host_pose as the host.

Enable is refused (with the reason) until a host pose is known; a host_pose in the wrong
frame and malformed goals are rejected without effect; once enabled, arm-only commands
follow the joint states, a moving host_pose moves the command, and the reaction at rest is
the links' weight at base_link.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, WrenchStamped
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_ik.host import ReactionModel
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.node

Q0 = [1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726]


def _pose(frame: str, x: float = 0.0, w: float = 1.0) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x = x
    msg.pose.orientation.w = w
    return msg


def test_enable_goal_and_host_pose_rules(rclpy_context, executor, wait_for):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from hyperarm_ik.host_compensation_node import HostCompensationNode

    # stale_timeout 5 s: the probe's states are sporadic (this test is about the rules)
    node = HostCompensationNode(context=rclpy_context, parameter_overrides=[
        Parameter("stale_timeout", value=5.0)])
    probe = Node("host_node_probe", namespace=contract.DEFAULT_NAMESPACE, context=rclpy_context)
    executor.add_node(node)
    executor.add_node(probe)
    commands, wrenches = [], []
    probe.create_subscription(JointState, contract.JOINT_COMMAND,
                              lambda m: commands.append(list(m.position)) if
                              list(m.name) == list(contract.ARM_JOINTS) else None,
                              qos_for(contract.JOINT_COMMAND))
    probe.create_subscription(WrenchStamped, contract.BASE_REACTION,
                              lambda m: wrenches.append(m), qos_for(contract.BASE_REACTION))
    states = probe.create_publisher(JointState, contract.JOINT_STATES,
                                    qos_for(contract.JOINT_STATES))
    host = probe.create_publisher(PoseStamped, contract.HOST_POSE, qos_for(contract.HOST_POSE))
    goal = probe.create_publisher(PoseStamped, contract.HOST_COMP_GOAL,
                                  qos_for(contract.HOST_COMP_GOAL))
    enable = probe.create_client(SetBool, contract.HOST_COMP_ENABLE)

    def send_state():
        msg = JointState()
        msg.header.stamp = probe.get_clock().now().to_msg()
        msg.name = list(contract.ARM_JOINTS)
        msg.position = list(Q0)
        states.publish(msg)

    def call(data: bool):
        wait_for(enable.service_is_ready, 10.0, what="enable service")
        fut = enable.call_async(SetBool.Request(data=data))
        wait_for(fut.done, 10.0, what="enable answer")
        return fut.result()

    try:
        wait_for(lambda: (send_state(), wrenches)[1], 10.0, period=0.02, what="reaction")
        w = wrenches[-1]
        assert w.header.frame_id == contract.BASE_FRAME
        kin = Kinematics(variant="arm")
        m, _c = ReactionModel(kin).mass_and_com(np.array(Q0))
        assert w.wrench.force.z == pytest.approx(-9.81 * m, rel=1e-6)
        res = call(True)
        assert not res.success and "host pose" in res.message
        host.publish(_pose("base_link"))                 # wrong frame: ignored
        send_state()
        res = call(True)
        assert not res.success
        for _ in range(3):
            host.publish(_pose(contract.WORLD_FRAME))
            send_state()
        wait_for(lambda: node._tracker.state is not None, 5.0, what="host pose taken")
        res = call(True)
        assert res.success, res.message
        wait_for(lambda: (send_state(), commands)[1], 5.0, period=0.02, what="arm commands")
        np.testing.assert_allclose(commands[-1], Q0, atol=1e-3)
        bad = _pose(contract.WORLD_FRAME, x=math.nan)
        goal.publish(bad)
        goal.publish(_pose(contract.WORLD_FRAME, w=0.5))   # not a unit quaternion
        before = node._loop.comp.goal.copy()
        # the host moves 2 cm along x: the command moves to keep the tool in the world
        for i in range(40):
            host.publish(_pose(contract.WORLD_FRAME, x=0.0005 * i))
            send_state()
            time.sleep(0.01)
        np.testing.assert_allclose(node._loop.comp.goal, before)
        wait_for(lambda: np.abs(np.array(commands[-1]) - Q0).max() > 0.01, 5.0,
                 what="the command compensating the host motion")
        assert call(False).success
        n = len(commands)
        for _ in range(5):
            send_state()
        time.sleep(0.2)
        assert len(commands) == n                          # no commands once disabled
    finally:
        executor.remove_node(node)
        executor.remove_node(probe)
        node.destroy_node()
        probe.destroy_node()
