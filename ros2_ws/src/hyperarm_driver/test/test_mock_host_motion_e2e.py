"""End-to-end tier: the mock's scripted host motion through the installed mock_driver.

host_pose (base_link in world) is published per step once a host motion is configured, at
rest until host_motion/enable true; with repeatability 0 the true tool pose
(debug/tool_pose_truth, world: MuJoCo's tool0) is FK of the true joints (joint_states) in
the moving root, host_pose times FK, before, while and after the base sways (the arm's
servos hold it, physically: within their friction band at rest, swaying on their
stiffness under the sway); enable false ramps it out back to rest (diagnostics show the
phases); a bad host-motion YAML is refused with its field named.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def _matrix(pose) -> np.ndarray:
    q = pose.orientation
    m = np.eye(4)
    m[:3, :3] = pin.Quaternion(q.w, q.x, q.y, q.z).toRotationMatrix()
    m[:3, 3] = (pose.position.x, pose.position.y, pose.position.z)
    return m


def _secs(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def _call(node, client, data: bool, wait_for):
    from std_srvs.srv import SetBool

    wait_for(client.service_is_ready, 20.0, what="host_motion/enable")
    fut = client.call_async(SetBool.Request(data=data))
    wait_for(fut.done, 10.0, what="host_motion/enable answered")
    return fut.result()


def test_host_pose_and_tool_truth_follow_the_scripted_sway(launch, rclpy_context, executor,
                                                          wait_for):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool

    from hyperarm_description import load_description
    from hyperarm_driver.mock.config import load_mock_config

    launch("hyperarm_driver", "mock_driver",
           params={"host_motion": "uav_sway", "repeatability": 0.0, "sim_speed": 4.0})
    probe = rclpy.create_node("probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    # (stamp, pose) lists, appended by the executor's thread (read: a copy, or the last)
    host: list[tuple[float, np.ndarray]] = []
    tool: list[tuple[float, np.ndarray]] = []
    probe.create_subscription(PoseStamped, contract.HOST_POSE,
                              lambda m: host.append((_secs(m.header.stamp), _matrix(m.pose))),
                              qos_for(contract.HOST_POSE))
    probe.create_subscription(
        PoseStamped, contract.TOOL_POSE_TRUTH,
        lambda m: tool.append((_secs(m.header.stamp), _matrix(m.pose)))
        if m.header.frame_id == contract.WORLD_FRAME else None,
        qos_for(contract.TOOL_POSE_TRUTH))
    phases: list[str] = []
    probe.create_subscription(
        DiagnosticArray, contract.DIAGNOSTICS,
        lambda m: phases.extend(kv.value for st in m.status if st.name.endswith("host_motion")
                                for kv in st.values if kv.key == "phase"),
        qos_for(contract.DIAGNOSTICS))
    enable = probe.create_client(SetBool, contract.HOST_MOTION_ENABLE)
    states: list = []
    probe.create_subscription(JointState, contract.JOINT_STATES, states.append,
                              qos_for(contract.JOINT_STATES))
    desc = load_description()
    cfg = load_mock_config()                 # the node's work cell: the packaged one

    def joints(msg) -> tuple[np.ndarray, np.ndarray]:
        """The arm's joint positions and velocities of a joint_states message."""
        idx = [msg.name.index(n) for n in contract.ARM_JOINTS]
        return np.array(msg.position)[idx], np.array(msg.velocity)[idx]

    # The servos stop within their Coulomb friction over their stiffness of a goal (the
    # largest friction a servo draws: 1.5 x the nominal).
    band = 1.5 * cfg.current.friction / cfg.servo.stiffness          # rad

    def fk_error(stamp: float, states_at: dict) -> float:
        """|truth - host_pose x FK(joint_states)| at ``stamp`` (m and rotation entries)."""
        q, _ = states_at[stamp]
        return float(np.abs(tools[stamp] - hosts[stamp] @ desc.dh_forward(q)).max())

    cmd = probe.create_publisher(JointState, contract.JOINT_COMMAND,
                                 qos_for(contract.JOINT_COMMAND))
    executor.add_node(probe)
    wait_for(lambda: host and tool, 30.0, what="host_pose and debug/tool_pose_truth")
    # at rest before the motion is enabled: world = base_link
    assert np.allclose(host[-1][1], np.eye(4), rtol=0.0, atol=1e-12)
    # a move (a new hidden offset per move, unless repeatability is 0): the truth is FK
    q = np.array([0.4, 0.3, 0.0, -0.3, 0.0, 0.2, 0.0, 0.0, 0.0])
    wait_for(lambda: cmd.get_subscription_count() > 0, 10.0, what="mock_driver subscribed")
    cmd.publish(JointState(name=list(contract.ARM_JOINTS), position=q.tolist()))

    def still_at_goal() -> bool:
        pos, vel = joints(states[-1])
        return np.abs(pos - q).max() <= band and np.abs(vel).max() < 1e-3

    wait_for(lambda: states and still_at_goal(), 20.0,
             what="joint_states at the commanded joints, within the friction band")

    def matched() -> tuple[dict, dict, dict]:
        """host_pose, truth and joint_states by stamp (copies)."""
        return dict(list(host)), dict(list(tool)), \
            {_secs(m.header.stamp): joints(m) for m in list(states)}

    hosts, tools, at = matched()
    last = max(set(hosts) & set(tools) & set(at))
    assert np.allclose(hosts[last], np.eye(4), rtol=0.0, atol=1e-12)
    assert fk_error(last, at) < 1e-12        # the truth is FK of the joints, at rest
    rest = tools[last].copy()

    res = _call(probe, enable, True, wait_for)
    assert res.success, res.message

    def swaying():
        latest = host[-1][1]
        return np.linalg.norm(latest[:3, 3]) > 0.012 or \
            np.arccos(np.clip(latest[2, 2], -1.0, 1.0)) > np.radians(4.0)

    wait_for(swaying, 20.0, what="host_pose swaying")
    wait_for(lambda: phases and phases[-1] == "on", 20.0, what="diagnostics: host_motion on")
    # the arm holds on its servos: the true tool is the base's motion times FK of the joints
    # (which the sway's inertial loads bend a little, on the servos' stiffness)
    hosts, tools, at = matched()
    stamps = sorted(set(hosts) & set(tools) & set(at))[-50:]
    assert len(stamps) >= 10
    moved = max(np.linalg.norm(tools[t][:3, 3] - rest[:3, 3]) for t in stamps)
    assert moved > 0.01
    for t in stamps:
        assert fk_error(t, at) < 1e-12, f"at {t} s: {fk_error(t, at):.3g}"

    res = _call(probe, enable, False, wait_for)
    assert res.success, res.message
    # ramped out (2 s of sim time): back at rest, and it stays there; the joints settle
    # back within their friction band, the truth FK of them
    wait_for(lambda: np.allclose(host[-1][1], np.eye(4), rtol=0.0, atol=1e-12), 20.0,
             what="host_pose back at rest")
    wait_for(still_at_goal, 10.0, what="the joints back at their goals")
    hosts, tools, at = matched()
    last = max(set(hosts) & set(tools) & set(at))
    assert np.allclose(hosts[last], np.eye(4), rtol=0.0, atol=1e-12)
    assert fk_error(last, at) < 1e-12
    wait_for(lambda: phases[-1] == "off", 10.0, what="diagnostics: host_motion off")
    assert "ramping_in" in phases or "ramping_out" in phases


def test_bad_host_motion_file_is_refused_with_its_field(launch, tmp_path, wait_for):
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema_version: 1\nbase:\n  - {axis: x, amplitude: -0.02, frequency: 0.5}\n")
    node = launch("hyperarm_driver", "mock_driver", params={"host_motion": str(bad)})
    wait_for(lambda: node.proc.poll() is not None, 30.0, what="mock_driver to exit")
    assert node.proc.returncode != 0
    out = node.output()
    assert "base[0].amplitude" in out and "minimum" in out, out[-2000:]
