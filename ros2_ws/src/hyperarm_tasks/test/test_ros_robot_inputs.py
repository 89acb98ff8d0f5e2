"""The task node's ROS inputs cost little (issue 28: task_node used 96-99 % of a core through
a block transfer, 15 % now (19 % before its task had a thread of its own); figures in
docs/benchmarks.md): its publishers and
subscriptions carry no QoS event handlers (rclpy's Python executor re-adds each handler to
its wait set on every wake), and ee_wrench (100 Hz from hybrid_force) is subscribed only
while someone asks for the wrench."""
from __future__ import annotations

import time

import pytest

pytestmark = [pytest.mark.node]


@pytest.fixture
def robot(rclpy_context, executor, desc):
    import rclpy

    from hyperarm_tasks.ros_robot import RosRobot

    node = rclpy.create_node("task_node_probe", namespace="/hyperarm", context=rclpy_context)
    rob = RosRobot(node, desc)
    executor.add_node(node)
    yield node, rob
    executor.remove_node(node)
    node.destroy_node()


def _topics(node) -> set[str]:
    return {s.topic_name for s in node.subscriptions}


def _handlers(node) -> int:
    return sum(1 for w in node.waitables if type(w).__name__ == "EventHandler")


def test_no_qos_event_handlers_on_the_task_nodes_topics(robot, rclpy_context):
    """As many event handlers as a bare node has (rclpy's own /parameter_events
    publisher's), none for the task node's topics."""
    import rclpy

    node, _rob = robot
    bare = rclpy.create_node("bare_probe", context=rclpy_context)
    try:
        assert _handlers(node) == _handlers(bare), \
            f"{_handlers(node) - _handlers(bare)} QoS event handlers on the task node's topics"
    finally:
        bare.destroy_node()
    assert len(list(node.subscriptions)) >= 3 and len(list(node.publishers)) >= 3


def test_ee_wrench_subscribed_only_while_asked_for(robot, rclpy_context, wait_for,
                                                   monkeypatch):
    import rclpy
    from geometry_msgs.msg import WrenchStamped

    from hyperarm_description import contract
    from hyperarm_description.qos import qos_for
    from hyperarm_tasks import ros_robot

    node, rob = robot
    monkeypatch.setattr(ros_robot, "WRENCH_IDLE", 0.5)
    full = f"/hyperarm/{contract.EE_WRENCH}".replace("//", "/")
    assert full not in _topics(node)
    pub_node = rclpy.create_node("wrench_source", namespace="/hyperarm", context=rclpy_context)
    pub = pub_node.create_publisher(WrenchStamped, contract.EE_WRENCH,
                                    qos_for(contract.EE_WRENCH))
    try:
        assert rob.wrench() is None               # the first call subscribes
        assert full in _topics(node)
        msg = WrenchStamped()
        msg.wrench.force.z = -4.5

        def heard():
            pub.publish(msg)
            w = rob.wrench()
            return w is not None and w[2] == -4.5
        wait_for(heard, 10.0, period=0.05, what="the wrench through the new subscription")
        rob.drop_idle_inputs()                    # asked for just now: kept
        assert full in _topics(node)
        time.sleep(0.6)
        rob.drop_idle_inputs()                    # 0.6 s without a call: dropped
        assert full not in _topics(node)
        assert rob.wrench() is None               # and a new call subscribes again
        assert full in _topics(node)
    finally:
        pub_node.destroy_node()
