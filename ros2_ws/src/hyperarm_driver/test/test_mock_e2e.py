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


class Comparison:
    """A probe node that records the diagnostics keys of every status and compares a real
    driver's interface with the mock's."""

    def __init__(self, rclpy_context, executor, wait_for) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray

        self.wait_for = wait_for
        self.probe = rclpy.create_node("probe", context=rclpy_context)
        self.statuses: dict[str, set] = {}
        self.probe.create_subscription(
            DiagnosticArray, contract.DIAGNOSTICS,
            lambda m: self.statuses.update({s.name: {kv.key for kv in s.values}
                                            for s in m.status}),
            qos_for(contract.DIAGNOSTICS))
        executor.add_node(self.probe)

    def interface(self, namespace: str, name: str, needs: dict[str, set]) -> dict:
        """The node's interface, once it exists and shows at least ``needs``."""
        def complete():
            if (name, namespace) not in self.probe.get_node_names_and_namespaces():
                return None
            got = _interface(self.probe, name, namespace)
            return got if all(needs[k] <= set(got[k]) for k in needs) else None

        return self.wait_for(complete, 30.0, what=f"the interface of {namespace}/{name}")

    def same_interface(self, real_ns: str, real_name: str, needs: dict[str, set],
                       shared_parameters: tuple[str, ...]) -> tuple[dict, dict]:
        """Assert: everything the real node offers, the mock offers with the same type;
        the shared parameters exist on both with the same type."""
        real = self.interface(real_ns, real_name, needs)
        mock = self.interface("/mock", "mock_driver", needs)
        for kind in needs:
            for name, types in real[kind].items():
                assert mock[kind].get(name) == types, \
                    f"{kind} {name}: {types} vs mock's {mock[kind].get(name)}"
        real_params = _parameters(self.probe, f"{real_ns}/{real_name}", self.wait_for)
        mock_params = _parameters(self.probe, "/mock/mock_driver", self.wait_for)
        for name in shared_parameters:
            assert name in real_params, f"{real_name} has no parameter {name} any more"
            assert mock_params.get(name) == real_params[name], name
        return real, mock

    def same_diagnostics(self, real_name: str, parts: list[str]) -> None:
        names = [f"{n}: {p}" for n in (real_name, "mock_driver") for p in parts]
        self.wait_for(lambda: all(n in self.statuses for n in names), 20.0,
                      what=f"diagnostics {names}")
        for part in parts:
            assert self.statuses[f"mock_driver: {part}"] == \
                self.statuses[f"{real_name}: {part}"], part


def test_mock_and_dynamixel_driver_expose_the_same_interface(launch, rclpy_context, executor,
                                                             wait_for, tmp_path):
    link = str(tmp_path / "ttyDXL")
    launch("hyperarm_driver", "dxl_emulator", "--link", link)
    wait_for(lambda: os.path.exists(link), 20.0, what="the emulator's pty")
    launch("hyperarm_driver", "dynamixel_driver", params={"port": link}, namespace="/dxl")
    launch("hyperarm_driver", "mock_driver", namespace="/mock")
    cmp = Comparison(rclpy_context, executor, wait_for)
    needs = {"publishers": {contract.JOINT_STATES, contract.DIAGNOSTICS},
             "subscriptions": {contract.JOINT_COMMAND},
             "services": {contract.SET_TORQUE, contract.REBOOT, contract.HOLD}}
    real, mock = cmp.same_interface("/dxl", "dynamixel_driver", needs, SHARED_PARAMETERS)
    # The mock adds only the camera, its ground truth (and /clock on sim time), nothing a
    # driver user needs.
    extra = set(mock["publishers"]) - set(real["publishers"])
    assert extra == {contract.DETECTIONS, contract.DETECTIONS_TRUTH, contract.TOOL_WRENCH_TRUTH,
                     contract.CONTACTS_TRUTH, contract.TOOL_POSE_TRUTH}
    cmp.same_diagnostics("dynamixel_driver",
                         ["bus"] + [f"joint{i}" for i in range(1, 10)] + ["gripper"])


def test_rail_variant_and_pmac_rail_driver_expose_the_same_interface(
        launch, rclpy_context, executor, wait_for):
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    launch("hyperarm_driver", "pmac_emulator", "--port", str(port))
    launch("hyperarm_driver", "pmac_rail_driver", params={"port": port}, namespace="/pmac")
    launch("hyperarm_driver", "mock_driver", params={"variant": "rail_arm"}, namespace="/mock")
    cmp = Comparison(rclpy_context, executor, wait_for)
    needs = {"publishers": {contract.JOINT_STATES, contract.DIAGNOSTICS},
             "subscriptions": {contract.JOINT_COMMAND},
             "services": {contract.RAIL_SET_TORQUE, contract.RAIL_HOLD, contract.RAIL_HOME}}
    cmp.same_interface("/pmac", "pmac_rail_driver", needs,
                       ("description_file", "rate", "require_homing", "diagnostics_period"))
    cmp.same_diagnostics("pmac_rail_driver", ["rail"])


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
    # MuJoCo's servos stop within their friction band of their goals, coulomb/kp, the
    # coulomb drawn per servo up to 1.5 x current.friction: the tool within that of each
    # joint through the arm's Jacobian
    import pinocchio as pin

    from hyperarm_description.pinocchio_model import build_model
    from hyperarm_driver.mock.config import load_mock_config

    cfg = load_mock_config()
    model = build_model(desc)
    jac = pin.computeFrameJacobian(model, model.createData(), q,
                                   model.getFrameId(desc.tool_frame),
                                   pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    band = 1.5 * cfg.current.friction / cfg.servo.stiffness
    tol = band * float(np.linalg.norm(jac, axis=0).sum())
    msg = JointState(name=[f"joint{i}" for i in range(1, 10)], position=q.tolist())
    wait_for(lambda: cmd.get_subscription_count() > 0, 10.0, what="mock_driver subscribed")
    cmd.publish(msg)

    def reached():
        p = poses[-1].pose.position
        return np.linalg.norm(np.array([p.x, p.y, p.z]) - target) <= tol

    wait_for(reached, 20.0, what="tool_pose at the commanded joints")
    (w0, c0), (w1, c1) = clocks[0], clocks[-1]
    assert (secs(c1) - secs(c0)) / (w1 - w0) > 1.5          # faster than real time
