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
from hyperarm_control.host import ReactionModel
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.node

Q0 = [1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726]


def _pose(frame: str, x: float = 0.0, w: float = 1.0) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x = x
    msg.pose.orientation.w = w
    return msg


def _send_state(probe, publisher) -> None:
    """One joint state of the nine arm joints at Q0, stamped now."""
    msg = JointState()
    msg.header.stamp = probe.get_clock().now().to_msg()
    msg.name = list(contract.ARM_JOINTS)
    msg.position = list(Q0)
    publisher.publish(msg)


def test_enable_goal_and_host_pose_rules(rclpy_context, executor, wait_for):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from hyperarm_control.host_compensation_node import HostCompensationNode

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
        _send_state(probe, states)

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


def test_reaction_takes_the_force_nodes_contact_wrench_and_the_hosts_acceleration(
        rclpy_context, executor, wait_for):
    """base_reaction adds the force node's ee_wrench_base (the wrench the tool applies, at
    tool0, base_link) by the statics: the arm then pushes its mount with its weight minus
    that wrench moved to base_link's origin; one in another frame or with a NaN is ignored;
    once older than contact_wrench_timeout it no longer counts. A host_pose accelerating
    at a along x adds -m a (the links' inertia) to the reaction's force."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from hyperarm_control.host_compensation_node import HostCompensationNode

    node = HostCompensationNode(context=rclpy_context, parameter_overrides=[
        Parameter("stale_timeout", value=5.0), Parameter("contact_wrench_timeout", value=2.0),
        Parameter("max_message_age", value=5.0)])
    probe = Node("host_wrench_probe", namespace=contract.DEFAULT_NAMESPACE,
                 context=rclpy_context)
    executor.add_node(node)
    executor.add_node(probe)
    wrenches: list = []
    probe.create_subscription(WrenchStamped, contract.BASE_REACTION,
                              lambda m: wrenches.append(m), qos_for(contract.BASE_REACTION))
    states = probe.create_publisher(JointState, contract.JOINT_STATES,
                                    qos_for(contract.JOINT_STATES))
    contact = probe.create_publisher(WrenchStamped, contract.EE_WRENCH_BASE,
                                     qos_for(contract.EE_WRENCH_BASE))
    host = probe.create_publisher(PoseStamped, contract.HOST_POSE, qos_for(contract.HOST_POSE))

    def send_state():
        _send_state(probe, states)

    def reaction() -> np.ndarray:
        n = len(wrenches)
        wait_for(lambda: (send_state(), len(wrenches) > n)[1], 5.0, period=0.02,
                 what="a reaction")
        w = wrenches[-1].wrench
        return np.array([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z])

    def publish_contact(w, frame=contract.BASE_FRAME):
        msg = WrenchStamped()
        msg.header.frame_id = frame
        f, t = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in w)
        contact.publish(msg)

    warnings: list[str] = []
    warn = node._warn
    node._warn = lambda text, reason=None: (warnings.append(text), warn(text, reason))[1]
    try:
        kin = Kinematics(variant="arm")
        model = ReactionModel(kin)
        mass, _ = model.mass_and_com(np.array(Q0))
        weight = reaction()
        w = np.array([0.5, -1.0, -3.0, 0.02, 0.05, -0.01])   # the tool presses down
        p_tool = kin.forward(np.array(Q0))[:3, 3]
        expected = weight - np.r_[w[:3], w[3:] + np.cross(p_tool, w[:3])]
        for i, (bad, frame) in enumerate(((w, "tool0"),
                                           (np.r_[w[:5], math.nan], contract.BASE_FRAME))):
            publish_contact(bad, frame)
            wait_for(lambda: sum(contract.EE_WRENCH_BASE in t for t in warnings) > i, 5.0,
                     what="the bad contact wrench refused")
            np.testing.assert_allclose(reaction(), weight, atol=1e-9)
        publish_contact(w)
        wait_for(lambda: np.abs(reaction() - expected).max() < 1e-6, 5.0,
                 what="the contact wrench in the reaction")
        time.sleep(2.1)                                      # older than the timeout
        np.testing.assert_allclose(reaction(), weight, atol=1e-9)
        # the host accelerates at 2 m/s² along x, its poses stamped 10 ms apart from now on
        # the node's clock (the acceleration comes from the stamps, whatever the gaps
        # between publications; max_message_age 5 s: a loaded machine's publications may
        # fall behind the stamps)
        a, t0 = 2.0, probe.get_clock().now().nanoseconds
        for i in range(30):
            t = 0.01 * i
            msg = _pose(contract.WORLD_FRAME, x=0.5 * a * t * t)
            ns = t0 + 10_000_000 * i
            msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 10**9, ns % 10**9
            host.publish(msg)
            time.sleep(0.005)
            send_state()
            time.sleep(0.005)
        got = reaction()
        assert got[0] == pytest.approx(weight[0] - mass * a, abs=0.05 * mass * a), (got, weight)
    finally:
        executor.remove_node(node)
        executor.remove_node(probe)
        node.destroy_node()
        probe.destroy_node()
