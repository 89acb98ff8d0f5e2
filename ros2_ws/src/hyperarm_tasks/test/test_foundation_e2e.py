"""End-to-end through the installed executables: mock_driver, fk_node and task_node as
separate processes over real DDS (private ROS_DOMAIN_ID), driven by the shell script."""
from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState

from hyperarm_description import contract, load_description
from hyperarm_description.qos import qos_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def _pose_xyz(msg: PoseStamped) -> np.ndarray:
    p = msg.pose.position
    return np.array([p.x, p.y, p.z])


@pytest.fixture
def probe(rclpy_context, executor):
    import rclpy

    node = rclpy.create_node("probe", namespace=contract.DEFAULT_NAMESPACE, context=rclpy_context)
    poses: list[PoseStamped] = []
    node.create_subscription(PoseStamped, contract.TOOL_POSE, poses.append,
                             qos_for(contract.TOOL_POSE))
    cmd = node.create_publisher(JointState, contract.JOINT_COMMAND, qos_for(contract.JOINT_COMMAND))
    executor.add_node(node)
    return poses, cmd


def test_fk_node_follows_mock_driver(launch, probe, wait_for):
    poses, cmd = probe
    launch("hyperarm_driver", "mock_driver")
    launch("hyperarm_ik", "fk_node")
    desc = load_description()
    wait_for(lambda: poses, 20.0, what="tool_pose from fk_node")
    assert poses[-1].header.frame_id == "base_link"
    assert _pose_xyz(poses[-1]) == pytest.approx(desc.dh_forward(np.zeros(9))[:3, 3], abs=1e-9)

    q = np.array([0.3, -0.4, 0.2, 0.5, -0.1, 0.3, 0.2, -0.6, 0.4])
    target = desc.dh_forward(q)[:3, 3]
    msg = JointState(name=[f"joint{i}" for i in range(1, 10)], position=q.tolist())

    def reached():
        cmd.publish(msg)  # re-sent until matched: the first may precede discovery
        return np.allclose(_pose_xyz(poses[-1]), target, atol=1e-6)

    wait_for(reached, 20.0, period=0.1, what="tool_pose at the commanded joints")


def test_ready_script_drives_mock_to_ready_pose(launch, probe, wait_for, ros_domain, executable):
    poses, cmd = probe
    launch("hyperarm_driver", "mock_driver")
    launch("hyperarm_ik", "fk_node")
    launch("hyperarm_tasks", "task_node")
    wait_for(lambda: poses, 20.0, what="tool_pose from fk_node")
    # move away first, so that "ready" has something to do
    away = JointState(name=["joint2", "joint4"], position=[0.8, -0.8])
    desc = load_description()
    away_xyz = desc.dh_forward(np.array([0, 0.8, 0, -0.8, 0, 0, 0, 0, 0]))[:3, 3]

    def moved():
        cmd.publish(away)
        return np.allclose(_pose_xyz(poses[-1]), away_xyz, atol=1e-6)

    wait_for(moved, 20.0, period=0.1, what="the arm to move away from ready")
    script = os.path.join(os.path.dirname(executable("hyperarm_tasks", "run_task")),
                          "ready.sh")
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain))
    done = subprocess.run([script, "--timeout", "60"], env=env, capture_output=True, text=True,
                          timeout=90)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "ready_pose" in done.stdout and "succeeded" in done.stdout
    ready_xyz = desc.dh_forward(np.zeros(9))[:3, 3]
    wait_for(lambda: np.allclose(_pose_xyz(poses[-1]), ready_xyz, atol=0.02), 10.0,
             what="tool_pose at the ready pose")


def test_unknown_task_fails_with_message(launch, ros_domain, executable):
    launch("hyperarm_driver", "mock_driver")
    launch("hyperarm_tasks", "task_node")
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain))
    done = subprocess.run([executable("hyperarm_tasks", "run_task"), "dance"], env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "unknown task 'dance'" in done.stdout + done.stderr


def test_bad_description_file_exits_with_clear_message(launch, wait_for, tmp_path):
    proc = launch("hyperarm_tasks", "task_node",
                  params={"description_file": str(tmp_path / "missing.yaml")})
    wait_for(lambda: proc.proc.poll() is not None, 20.0, what="task_node to exit")
    assert proc.proc.returncode == 1
    assert "cannot read robot description" in proc.output()
    assert "Traceback" not in proc.output()
