"""E2E: the installed mock_driver, fk_node and tf_publisher on a private ROS domain.

A subscriber to /tf and /tf_static finds every link of the installed URDF (the one
robot_state_publisher gets on the robot), the fixed joints in one latched /tf_static
message; while the arm (and the rail) moves, world -> ... -> tool0 composed from the TF
message of a joint_states stamp equals fk_node's tool_pose of the same stamp within 1e-9,
on both variants.
"""
from __future__ import annotations

import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

TOL = 1e-9


def _matrix(translation, rotation) -> np.ndarray:
    import pinocchio as pin

    t = np.eye(4)
    t[:3, :3] = pin.Quaternion(rotation.w, rotation.x, rotation.y,
                               rotation.z).toRotationMatrix()
    t[:3, 3] = (translation.x, translation.y, translation.z)
    return t


def _compose(transforms, root: str) -> dict[str, np.ndarray]:
    by_parent: dict[str, list] = {}
    for t in transforms:
        by_parent.setdefault(t.header.frame_id, []).append(t)
    out, todo = {root: np.eye(4)}, [root]
    while todo:
        parent = todo.pop()
        for t in by_parent.get(parent, ()):
            out[t.child_frame_id] = out[parent] @ _matrix(t.transform.translation,
                                                          t.transform.rotation)
            todo.append(t.child_frame_id)
    return out


def _installed_links(variant: str) -> set[str]:
    from ament_index_python.packages import get_package_share_directory

    urdf = Path(get_package_share_directory("hyperarm_description")) / "urdf" / \
        f"hyperarm_{variant}.urdf"
    return {link.get("name") for link in ET.parse(urdf).getroot().iter("link")}


@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
def test_tf_frames_compose_to_fk_nodes_tool_pose(variant, launch, rclpy_context, executor,
                                                 wait_for):
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState
    from tf2_msgs.msg import TFMessage

    rail = variant == "rail_arm"
    mock = launch("hyperarm_driver", "mock_driver",
                  params={"variant": variant, "require_homing": False} if rail
                  else {"variant": variant})
    fk = launch("hyperarm_ik", "fk_node", params={"variant": variant})
    tfp = launch("hyperarm_ik", "tf_publisher", params={"variant": variant})
    probe = rclpy.create_node("tf_e2e_probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    lock = threading.Lock()
    tf: dict[tuple[int, int], list] = {}
    static: list = []
    poses: list = []

    def on_tf(msg):
        with lock:
            for t in msg.transforms:
                tf.setdefault((t.header.stamp.sec, t.header.stamp.nanosec), []).append(t)

    probe.create_subscription(TFMessage, contract.TF, on_tf, qos_for(contract.TF))
    probe.create_subscription(TFMessage, contract.TF_STATIC, static.append,
                              qos_for(contract.TF_STATIC))
    probe.create_subscription(PoseStamped, contract.TOOL_POSE, poses.append,
                              qos_for(contract.TOOL_POSE))
    cmd = probe.create_publisher(JointState, contract.JOINT_COMMAND,
                                 qos_for(contract.JOINT_COMMAND))
    executor.add_node(probe)

    def up():
        for item in (mock, fk, tfp):
            assert item.proc.poll() is None, item.output()[-3000:]
        return static and tf and poses
    wait_for(up, 60.0, period=0.1, what="/tf_static, /tf and tool_pose")
    assert "tf_publisher: " + variant in tfp.output()

    # every link of the installed URDF, the fixed ones in one latched message
    root = "world" if rail else "base_link"
    assert len(static) == 1
    fixed = {t.child_frame_id for t in static[0].transforms}
    assert fixed == {"camera_link", "tool0"} | ({"base_link"} if rail else set())
    with lock:
        moving = {t.child_frame_id for ts in tf.values() for t in ts}
    assert {root} | fixed | moving == _installed_links(variant)
    assert not fixed & moving

    # move: 9 joints (and the rail) at once, then compare every stamp both topics carry
    rng = np.random.default_rng(26 + rail)
    q = rng.uniform(-1.2, 1.2, 9)
    names = list(contract.ARM_JOINTS) + (["rail"] if rail else [])
    target = [*q, 0.3] if rail else list(q)
    wait_for(lambda: cmd.get_subscription_count() > 0, 20.0, what="mock_driver subscribed")
    start = len(poses)
    cmd.publish(JointState(name=names, position=[float(v) for v in target]))
    time.sleep(2.5)
    with lock:
        by_stamp = {k: list(v) for k, v in tf.items()}
    matched = []
    for pose in poses[start:]:
        key = (pose.header.stamp.sec, pose.header.stamp.nanosec)
        if key not in by_stamp:
            continue
        frames = _compose(static[0].transforms + by_stamp[key], root)
        want = _matrix(pose.pose.position, pose.pose.orientation)
        assert pose.header.frame_id == root
        matched.append((float(np.max(np.abs(frames["tool0"] - want))), want[:3, 3]))
    assert len(matched) >= 20, f"{len(matched)} stamps in both tool_pose and /tf"
    worst = max(d for d, _p in matched)
    assert worst < TOL, worst
    travel = np.ptp(np.array([p for _d, p in matched]), axis=0)
    assert np.linalg.norm(travel) > 0.05, "the arm did not move while compared"
    print(f"{variant}: {len(matched)} stamps compared, max |TF - tool_pose| {worst:.2e}")
