"""E2E (issue 24, item 3): the installed task_node rejects late, out-of-order, future and
malformed joint_states and detections; each kind is logged (naming the field, throttled
per kind: three kinds in a row are three lines) and counted in its diagnostics
('task_node: inputs'). Before, a joint_states stamped 2 s ago was used without a word, and
a NaN detection position went into the averages."""
from __future__ import annotations

import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_interfaces.msg import Detections

pytestmark = [pytest.mark.e2e]

ARM = [f"joint{i}" for i in range(1, 10)] + ["gripper"]


def _stamp(msg, t: float) -> None:
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))


def test_task_node_rejects_late_and_malformed_inputs(launch, rclpy_context, executor, wait_for):
    import rclpy

    task = launch("hyperarm_tasks", "task_node")
    wait_for(lambda: "task_node ready" in task.output(), 60.0, what="task_node")
    node = rclpy.create_node("inputs_probe", namespace=contract.DEFAULT_NAMESPACE,
                             context=rclpy_context)
    diags: list = []
    node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                             lambda m: diags.extend(s for s in m.status
                                                    if s.name == "task_node: inputs"),
                             qos_for(contract.DIAGNOSTICS))
    states = node.create_publisher(JointState, contract.JOINT_STATES,
                                   qos_for(contract.JOINT_STATES))
    dets = node.create_publisher(Detections, contract.DETECTIONS, qos_for(contract.DETECTIONS))
    executor.add_node(node)
    wait_for(lambda: states.get_subscription_count() > 0 and dets.get_subscription_count() > 0,
             20.0, what="task_node's subscriptions")

    def now() -> float:
        return node.get_clock().now().nanoseconds * 1e-9

    def state(t: float, position=None, effort=None) -> None:
        msg = JointState(name=ARM, position=position or [0.0] * 10,
                         velocity=[0.0] * 10, effort=effort or [0.0] * 10)
        _stamp(msg, t)
        states.publish(msg)
        time.sleep(0.05)

    def detection(t: float, xyz=(0.1, 0.2, 0.6), q=(0.0, 0.0, 0.0, 1.0), frame="camera_link"):
        msg = Detections(names=["block"])
        msg.header.frame_id = frame
        p = Pose()
        p.position.x, p.position.y, p.position.z = xyz
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = q
        msg.poses = [p]
        _stamp(msg, t)
        dets.publish(msg)
        time.sleep(0.05)

    t0 = now()
    state(t0)                                     # used
    state(now() - 2.0, position=[0.03] * 10)      # the late message
    state(t0 - 0.1)                               # older than the newest used
    state(now() + 5.0)                            # a skewed clock
    state(now(), position=[0.0] * 9 + [float("nan")])
    state(now(), effort=[0.0] * 3 + [float("inf")] + [0.0] * 6)
    detection(now())                              # used
    detection(now(), xyz=(float("nan"), 0.2, 0.6))
    detection(now(), xyz=(0.1, float("inf"), 0.6))
    detection(now(), q=(0.0, 0.0, 0.0, 0.0))
    detection(now() - 3.0)
    detection(now(), frame="base_link")
    expected = {
        "joint_states_rejected_stale": 1, "joint_states_rejected_out_of_order": 1,
        "joint_states_rejected_future": 1, "joint_states_rejected_position_nan": 1,
        "joint_states_rejected_effort_inf": 1, "joint_states_accepted": 1,
        "detections_rejected_position_nan": 1, "detections_rejected_position_inf": 1,
        "detections_rejected_quaternion_norm": 1, "detections_rejected_stale": 1,
        "detections_rejected_frame": 1, "detections_accepted": 1}

    def counted():
        if not diags:
            return None
        values = {kv.key: int(kv.value) for kv in diags[-1].values}
        return values if all(values.get(k) == v for k, v in expected.items()) else None

    wait_for(counted, 10.0, what=f"diagnostics counts {expected} (last: "
             f"{[(kv.key, kv.value) for kv in diags[-1].values] if diags else None})")
    log = task.output()
    for line in ("joint_states from joint1..gripper (10 joints) ignored: stamped 2.",
                 "s before the newest one used",
                 "s in the future (clock skew?)",
                 "joint_states ignored: position of gripper is NaN",
                 "joint_states ignored: effort of joint4 is inf",
                 "detections ignored: poses[0] ('block'): pose.position.x is NaN",
                 "detections ignored: poses[0] ('block'): pose.position.y is inf",
                 "detections ignored: poses[0] ('block'): pose.orientation is not a unit",
                 "older than max_age 1 s",
                 "detections ignored: header.frame_id is 'base_link'"):
        assert line in log, f"{line!r} not logged:\n{log[-3000:]}"
