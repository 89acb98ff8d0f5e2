"""Node tier: tf_publisher in-process on rail_arm, fed joint_states by a probe.

/tf_static reaches a subscriber that joins later (transient local), all fixed joints in one
TFMessage; robot_description is the generated URDF. Each good joint_states gives one
TFMessage with its joints' transforms and its stamp; a malformed one (NaN, a length
mismatch, an unknown name) gives nothing, nor does a late, out-of-order, future or
unstamped one, while another driver's joint set keeps its own order. Each is counted in
/diagnostics.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.qos import qos_for
from hyperarm_description.urdf import generate_urdf

pytestmark = pytest.mark.node

ARM = [*contract.ARM_JOINTS, contract.GRIPPER_JOINT]


def _state(probe, names, position, age: float = 0.0, stamp: float | None = None,
           **fields) -> JointState:
    """joint_states stamped ``stamp`` (s), else ``age`` s ago."""
    msg = JointState(name=list(names), position=[float(v) for v in position], **fields)
    if stamp is None:
        stamp = probe.get_clock().now().nanoseconds * 1e-9 - age
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(stamp), int(stamp % 1.0 * 1e9)
    return msg


def test_tf_publisher_publishes_good_states_and_counts_the_rest(rclpy_context, executor,
                                                                wait_for):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from hyperarm_ik.tf_publisher_node import TfPublisherNode

    node = TfPublisherNode(context=rclpy_context, parameter_overrides=[
        Parameter("variant", value="rail_arm"), Parameter("max_state_age", value=10.0),
        Parameter("diagnostics_period", value=0.2)])
    executor.add_node(node)
    time.sleep(0.3)   # the static message is out before anyone listens
    probe = Node("tf_probe", namespace=contract.DEFAULT_NAMESPACE, context=rclpy_context)
    tf, static, urdf, diags = [], [], [], []
    probe.create_subscription(TFMessage, contract.TF, tf.append, qos_for(contract.TF))
    probe.create_subscription(TFMessage, contract.TF_STATIC, static.append,
                              qos_for(contract.TF_STATIC))
    probe.create_subscription(String, contract.ROBOT_DESCRIPTION, urdf.append,
                              qos_for(contract.ROBOT_DESCRIPTION))
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: diags.extend(s for s in m.status
                                                     if s.name.startswith("tf_publisher")),
                              qos_for(contract.DIAGNOSTICS))
    states = probe.create_publisher(JointState, contract.JOINT_STATES,
                                    qos_for(contract.JOINT_STATES))
    executor.add_node(probe)
    wait_for(lambda: static and urdf, 10.0, what="/tf_static and robot_description")
    assert len(static) == 1
    assert {(t.header.frame_id, t.child_frame_id) for t in static[0].transforms} == {
        ("world", "camera_link"), ("rail_carriage", "base_link"), ("link9", "tool0")}
    assert urdf[0].data == generate_urdf(load_description(variant="rail_arm"))
    wait_for(lambda: states.get_subscription_count() > 0, 10.0, what="tf_publisher subscribed")

    def send_and_settle(msg, expect_tf: bool):
        n = len(tf)
        states.publish(msg)
        if expect_tf:
            wait_for(lambda: len(tf) > n, 10.0, what="a /tf message")
        else:
            time.sleep(0.3)
        assert len(tf) == n + int(expect_tf), [m.transforms[0].child_frame_id for m in tf[n:]]
        return tf[-1] if expect_tf else None

    q = np.linspace(-1.0, 1.0, len(ARM))
    good = _state(probe, ARM, q, velocity=[0.0] * len(ARM))
    out = send_and_settle(good, True)
    assert [(t.header.frame_id, t.child_frame_id) for t in out.transforms] == [
        ("base_link", "link1"), *((f"link{i}", f"link{i + 1}") for i in range(1, 9)),
        ("tool0", "gripper_finger")]
    assert all(t.header.stamp == good.header.stamp for t in out.transforms)
    # malformed: rejected whole, nothing published
    send_and_settle(_state(probe, ARM, [*q[:-1], math.nan]), False)
    send_and_settle(_state(probe, ARM, q[:-1]), False)
    send_and_settle(_state(probe, ARM, q, effort=[0.0] * 3), False)
    send_and_settle(_state(probe, [*ARM[:-1], "elbow"], q), False)
    # late, out of order, from the future, unstamped
    good_stamp = good.header.stamp.sec + 1e-9 * good.header.stamp.nanosec
    send_and_settle(_state(probe, ARM, q, age=20.0), False)
    send_and_settle(_state(probe, ARM, q, stamp=good_stamp - 0.1), False)
    send_and_settle(_state(probe, ARM, q, age=-3.0), False)
    send_and_settle(JointState(name=ARM, position=q.tolist()), False)
    # another driver's joints (the rail) keep their own order: older than `good` is fine
    out = send_and_settle(_state(probe, ["rail"], [0.25], stamp=good_stamp - 0.05), True)
    (t,) = out.transforms
    assert (t.header.frame_id, t.child_frame_id) == ("world", "rail_carriage")
    assert t.transform.translation.x == pytest.approx(0.25, abs=1e-12)
    # and the arm goes on
    out = send_and_settle(_state(probe, ARM, -q), True)
    assert len(out.transforms) == len(ARM)

    def counted():
        if not diags:
            return None
        values = {kv.key: kv.value for kv in diags[-1].values}
        return values if values.get("published") == "3" and values.get("unstamped") == "1" \
            else None
    values = wait_for(counted, 10.0, what="diagnostics with every count")
    assert {k: values[k] for k in ("published", "malformed", "stale", "out_of_order",
                                   "future", "unstamped")} == {
        "published": "3", "malformed": "4", "stale": "1", "out_of_order": "1",
        "future": "1", "unstamped": "1"}
    assert diags[-1].level == b"\x01" and "8 not used" in diags[-1].message, diags[-1]
