"""End-to-end tier: installed executables as separate processes.

- The mock and the real Dynamixel driver (on the pty emulator), and the mock's rail variant
  and the PMAC rail driver (on the TCP emulator), expose the same topic and service names
  and types, the same parameters (where they apply) and the same diagnostics keys:
  higher-level nodes cannot tell them apart.
- On sim time the mock publishes /clock and a node with use_sim_time follows it.
"""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

# Parameters of the Dynamixel driver that apply to the mock too (docs/dynamixel.md).
SHARED_PARAMETERS = ("description_file", "rate", "command_timeout", "torque_on_start",
                     "shutdown_torque", "diagnostics_period")


def _interface(node, name: str, namespace: str) -> dict[str, set]:
    """Relative names -> types of what node ``namespace/name`` publishes, subscribes and
    serves (parameter services and rosout left out)."""
    def rel(items):
        out = {}
        for topic, types in items:
            if topic.startswith(namespace + "/"):
                topic = topic[len(namespace) + 1:]
            if topic.startswith(f"{name}/") or topic == "/rosout":
                continue   # parameter services, rosout
            out[topic] = tuple(types)
        return out

    return {
        "publishers": rel(node.get_publisher_names_and_types_by_node(name, namespace)),
        "subscriptions": rel(node.get_subscriber_names_and_types_by_node(name, namespace)),
        "services": rel(node.get_service_names_and_types_by_node(name, namespace)),
    }


def _parameters(node, target: str, wait_for) -> dict[str, int]:
    """Names -> ParameterType of the parameters of node ``target`` (full name)."""
    from rcl_interfaces.srv import DescribeParameters, ListParameters

    lister = node.create_client(ListParameters, f"{target}/list_parameters")
    describer = node.create_client(DescribeParameters, f"{target}/describe_parameters")
    wait_for(lister.service_is_ready, 20.0, what=f"{target}/list_parameters")
    fut = lister.call_async(ListParameters.Request())
    wait_for(fut.done, 10.0, what="list_parameters")
    names = list(fut.result().result.names)
    wait_for(describer.service_is_ready, 10.0, what=f"{target}/describe_parameters")
    fut = describer.call_async(DescribeParameters.Request(names=names))
    wait_for(fut.done, 10.0, what="describe_parameters")
    return {d.name: d.type for d in fut.result().descriptors}


def test_mock_and_dynamixel_driver_expose_the_same_interface(launch, rclpy_context, executor,
                                                             wait_for, tmp_path):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    link = str(tmp_path / "ttyDXL")
    launch("hyperarm_driver", "dxl_emulator", "--link", link)
    wait_for(lambda: os.path.exists(link), 20.0, what="the emulator's pty")
    dxl = launch("hyperarm_driver", "dynamixel_driver", params={"port": link},
                 namespace="/dxl")
    launch("hyperarm_driver", "mock_driver", namespace="/mock")
    probe = rclpy.create_node("probe", context=rclpy_context)
    statuses: dict[str, dict] = {}
    probe.create_subscription(
        DiagnosticArray, contract.DIAGNOSTICS,
        lambda m: statuses.update({s.name: {kv.key for kv in s.values} for s in m.status}),
        qos_for(contract.DIAGNOSTICS))
    executor.add_node(probe)

    def both_up():
        names = probe.get_node_names_and_namespaces()
        return ("dynamixel_driver", "/dxl") in names and ("mock_driver", "/mock") in names

    wait_for(both_up, 30.0, what=f"both nodes (driver log: {dxl.output()[-500:]})")
    expected = {"publishers", "subscriptions", "services"}

    def complete(ns, name, needs):
        got = _interface(probe, name, ns)
        return got if all(needs[k] <= set(got[k]) for k in expected) else None

    needs = {"publishers": {contract.JOINT_STATES, contract.DIAGNOSTICS},
             "subscriptions": {contract.JOINT_COMMAND},
             "services": {contract.SET_TORQUE, contract.REBOOT, contract.HOLD}}
    real = wait_for(lambda: complete("/dxl", "dynamixel_driver", needs), 20.0,
                    what="the Dynamixel driver's interface")
    mock = wait_for(lambda: complete("/mock", "mock_driver", needs), 20.0,
                    what="the mock's interface")
    for kind in expected:
        for name, types in real[kind].items():
            assert mock[kind].get(name) == types, f"{kind} {name}: {types} vs mock's " \
                                                  f"{mock[kind].get(name)}"
    # The mock adds only the camera (and /clock on sim time), nothing a driver user needs.
    extra = set(mock["publishers"]) - set(real["publishers"])
    assert extra == {contract.DETECTIONS, contract.DETECTIONS_TRUTH}

    real_params = _parameters(probe, "/dxl/dynamixel_driver", wait_for)
    mock_params = _parameters(probe, "/mock/mock_driver", wait_for)
    for name in SHARED_PARAMETERS:
        assert name in real_params, f"the Dynamixel driver has no parameter {name} any more"
        assert mock_params.get(name) == real_params[name], name

    def diag_pair():
        return ("dynamixel_driver: joint1" in statuses and "mock_driver: joint1" in statuses
                and "dynamixel_driver: bus" in statuses and "mock_driver: bus" in statuses)

    wait_for(diag_pair, 20.0, what="diagnostics of both")
    for part in ["bus"] + [f"joint{i}" for i in range(1, 10)] + ["gripper"]:
        assert statuses[f"mock_driver: {part}"] == statuses[f"dynamixel_driver: {part}"], part


def test_rail_variant_and_pmac_rail_driver_expose_the_same_interface(
        launch, rclpy_context, executor, wait_for):
    import socket

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    launch("hyperarm_driver", "pmac_emulator", "--port", str(port))
    launch("hyperarm_driver", "pmac_rail_driver", params={"port": port}, namespace="/pmac")
    launch("hyperarm_driver", "mock_driver", params={"variant": "rail_arm"}, namespace="/mock")
    probe = rclpy.create_node("probe", context=rclpy_context)
    statuses: dict[str, set] = {}
    probe.create_subscription(
        DiagnosticArray, contract.DIAGNOSTICS,
        lambda m: statuses.update({s.name: {kv.key for kv in s.values} for s in m.status}),
        qos_for(contract.DIAGNOSTICS))
    executor.add_node(probe)
    needs = {"publishers": {contract.JOINT_STATES, contract.DIAGNOSTICS},
             "subscriptions": {contract.JOINT_COMMAND},
             "services": {contract.SET_TORQUE, contract.HOLD, contract.RAIL_HOME}}

    def complete(ns, name):
        if (name, ns) not in probe.get_node_names_and_namespaces():
            return None
        got = _interface(probe, name, ns)
        return got if all(needs[k] <= set(got[k]) for k in needs) else None

    real = wait_for(lambda: complete("/pmac", "pmac_rail_driver"), 30.0,
                    what="the PMAC driver's interface")
    mock = wait_for(lambda: complete("/mock", "mock_driver"), 30.0, what="the mock's interface")
    for kind in needs:
        for name, types in real[kind].items():
            assert mock[kind].get(name) == types, f"{kind} {name}"
    real_params = _parameters(probe, "/pmac/pmac_rail_driver", wait_for)
    mock_params = _parameters(probe, "/mock/mock_driver", wait_for)
    for name in ("description_file", "rate", "require_homing", "diagnostics_period"):
        assert name in real_params, f"the PMAC driver has no parameter {name} any more"
        assert mock_params.get(name) == real_params[name], name
    wait_for(lambda: "pmac_rail_driver: rail" in statuses and "mock_driver: rail" in statuses,
             20.0, what="rail diagnostics of both")
    assert statuses["mock_driver: rail"] == statuses["pmac_rail_driver: rail"]


def test_sim_time_clock_drives_use_sim_time_nodes(launch, rclpy_context, executor, wait_for):
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from hyperarm_description import load_description

    launch("hyperarm_driver", "mock_driver", params={"sim_speed": 5.0})
    launch("hyperarm_ik", "fk_node", params={"use_sim_time": True})
    probe = rclpy.create_node("probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    poses: list = []
    clocks: list = []
    probe.create_subscription(PoseStamped, contract.TOOL_POSE, poses.append,
                              qos_for(contract.TOOL_POSE))
    probe.create_subscription(Clock, contract.CLOCK,
                              lambda m: clocks.append((time.monotonic(), m.clock)),
                              QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    cmd = probe.create_publisher(JointState, contract.JOINT_COMMAND,
                                 qos_for(contract.JOINT_COMMAND))
    executor.add_node(probe)
    wait_for(lambda: poses and len(clocks) > 5, 30.0, what="tool_pose and /clock")

    def secs(t):
        return t.sec + 1e-9 * t.nanosec

    # fk_node stamps with the simulated time of the joint_states (near /clock, far from
    # the wall clock's epoch seconds)
    assert abs(secs(poses[-1].header.stamp) - secs(clocks[-1][1])) < 1.0
    assert secs(poses[-1].header.stamp) < 1000.0
    # a 2 rad move (0.97 s of simulated time at 3 rad/s, 10 rad/s²) reached through fk_node
    desc = load_description()
    q = np.zeros(9)
    q[0] = 2.0
    target = desc.dh_forward(q)[:3, 3]
    msg = JointState(name=[f"joint{i}" for i in range(1, 10)], position=q.tolist())
    wait_for(lambda: cmd.get_subscription_count() > 0, 10.0, what="mock_driver subscribed")
    cmd.publish(msg)

    def reached():
        p = poses[-1].pose.position
        return np.allclose([p.x, p.y, p.z], target, atol=1e-6)

    wait_for(reached, 20.0, what="tool_pose at the commanded joints")
    (w0, c0), (w1, c1) = clocks[0], clocks[-1]
    assert (secs(c1) - secs(c0)) / (w1 - w0) > 1.5          # faster than real time
