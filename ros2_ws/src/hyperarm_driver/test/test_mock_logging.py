"""E2E: the installed mock_driver throttles its command logs per reason, not per call site
(issue 17, "Throttling must not hide a different error")."""
from __future__ import annotations

import time

import pytest
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.qos import qos_for

pytestmark = pytest.mark.e2e


def _mock_and_probe(launch, rclpy_context, executor, wait_for, name):
    """The installed mock_driver, a joint_command publisher and the joint_states seen."""
    from rclpy.node import Node

    mock = launch("hyperarm_driver", "mock_driver")
    node = Node(name, namespace=contract.DEFAULT_NAMESPACE, context=rclpy_context)
    executor.add_node(node)
    pub = node.create_publisher(JointState, contract.JOINT_COMMAND,
                                qos_for(contract.JOINT_COMMAND))
    states: list[JointState] = []
    node.create_subscription(JointState, contract.JOINT_STATES, states.append,
                             qos_for(contract.JOINT_STATES))
    wait_for(lambda: states and pub.get_subscription_count() > 0, 30.0,
             what="mock up and subscribed")
    return mock, pub, states


def test_a_new_kind_of_rejection_is_logged_at_once(launch, rclpy_context, executor, wait_for):
    mock, pub, _states = _mock_and_probe(launch, rclpy_context, executor, wait_for, "log_probe")

    def send(names, positions):
        pub.publish(JointState(name=names, position=positions))

    send(["joint1", "joint1"], [0.1, 0.2])                     # duplicate name
    wait_for(lambda: "duplicate" in mock.output(), 5.0, what="duplicate-name rejection")
    time.sleep(0.3)                                             # within the 1 s throttle
    send(["joint1", "elbow"], [0.1, 0.2])                       # another reason
    wait_for(lambda: "elbow" in mock.output(), 5.0,
             what="the unknown-joint rejection logged 0.3 s after another kind")
    for _ in range(5):                                          # the same reason again:
        send(["joint1", "elbow"], [0.1, 0.2])                   # throttled
        time.sleep(0.02)
    time.sleep(0.3)
    assert mock.output().count("elbow") == 1, mock.output()[-2000:]


def test_a_bad_velocity_rejects_the_whole_command(launch, rclpy_context, executor, wait_for):
    mock, pub, states = _mock_and_probe(launch, rclpy_context, executor, wait_for, "vel_probe")
    start = states[-1].position[0]
    # one at a time: joint_command keeps only the newest message (depth 1)
    pub.publish(JointState(name=["joint1"], position=[start + 0.3], velocity=[float("nan")]))
    wait_for(lambda: "non-finite velocity" in mock.output(), 5.0, what="NaN velocity refused")
    pub.publish(JointState(name=["joint2"], position=[0.2], velocity=[0.1, 0.1, 0.1]))
    wait_for(lambda: "velocity: 3 values" in mock.output(), 5.0, what="length refused")
    time.sleep(0.5)
    last = states[-1]
    assert abs(last.position[0] - start) < 1e-3 and abs(last.position[1]) < 0.05, last.position
