"""Node tier: mock_driver in-process with an executor (topics, services, bad input, watchdog,
camera, sim time, rail variant)."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for

pytestmark = pytest.mark.node

ARM = [f"joint{i}" for i in range(1, 10)]


class Probe:
    """Test-side node: records joint_states, diagnostics, detections, /clock; sends commands
    and calls services."""

    def __init__(self, context, executor, namespace: str = contract.DEFAULT_NAMESPACE) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_srvs.srv import SetBool, Trigger

        from hyperarm_interfaces.msg import Detections
        from hyperarm_interfaces.srv import Reboot

        self.node = rclpy.create_node("probe", namespace=namespace, context=context)
        self.states: list = []
        self.diags: list = []
        self.detections: list = []
        self.truth: list = []
        self.clock: list = []
        n = self.node
        n.create_subscription(JointState, contract.JOINT_STATES,
                              lambda m: self.states.append((time.monotonic(), m)),
                              qos_for(contract.JOINT_STATES))
        n.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: self.diags.extend(m.status), qos_for(contract.DIAGNOSTICS))
        n.create_subscription(Detections, contract.DETECTIONS, self.detections.append,
                              qos_for(contract.DETECTIONS))
        n.create_subscription(Detections, contract.DETECTIONS_TRUTH, self.truth.append,
                              qos_for(contract.DETECTIONS_TRUTH))
        n.create_subscription(Clock, contract.CLOCK,
                              lambda m: self.clock.append((time.monotonic(), m)),
                              QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.pub = n.create_publisher(JointState, contract.JOINT_COMMAND,
                                      qos_for(contract.JOINT_COMMAND))
        self.types = {contract.SET_TORQUE: SetBool, contract.HOLD: Trigger,
                      contract.REBOOT: Reboot, contract.RAIL_HOME: Trigger,
                      contract.RAIL_SET_TORQUE: SetBool, contract.RAIL_HOLD: Trigger}
        self.clients = {name: n.create_client(t, name) for name, t in self.types.items()}
        self.JointState = JointState
        executor.add_node(n)

    def call(self, name: str, wait_for, **fields):
        cli = self.clients[name]
        wait_for(cli.service_is_ready, 10.0, what=f"service {cli.srv_name}")
        req = self.types[name].Request()
        for k, v in fields.items():
            setattr(req, k, v)
        fut = cli.call_async(req)
        wait_for(fut.done, 5.0, what=f"answer of {cli.srv_name}")
        return fut.result()

    def send(self, names, position=(), effort=()):
        deadline = time.monotonic() + 10.0         # the first message must not precede discovery
        while self.pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        self.pub.publish(self.JointState(name=list(names), position=list(position),
                                         effort=list(effort)))

    def position(self, joint: str) -> float:
        """The joint's position in the latest joint_states; NaN before the first one (a
        wait on it keeps waiting: it ran into an IndexError when the probe's subscription
        had not matched yet)."""
        if not self.states:
            return math.nan
        msg = self.states[-1][1]
        return msg.position[list(msg.name).index(joint)]

    def settled(self, joint: str, value: float, tol: float, n: int = 40) -> bool:
        """Whether the joint's last ``n`` joint_states are all within ``tol`` of ``value``:
        at rest there (MuJoCo's servo may swing through its goal before it stops)."""
        if len(self.states) < n:
            return False
        for _, msg in self.states[-n:]:
            if abs(msg.position[list(msg.name).index(joint)] - value) > tol:
                return False
        return True

    def diag(self, name: str) -> dict:
        for st in reversed(self.diags):
            if st.name == name:
                return {kv.key: kv.value for kv in st.values}
        return {}


def band(node, joint: str) -> float:
    """How far from its goal the node's simulated servo of ``joint`` may rest: its Coulomb
    friction over its stiffness (MuJoCo's servo, test_mock_sim.py)."""
    sim = node._sim
    i = sim.names.index(joint)
    return float(sim.coulomb[i] / sim._kp[i])


def swing(node, joint: str, speed: float) -> float:
    """How far past its reference the servo can carry ``joint`` moving at ``speed`` when
    the reference stops (its spring takes the kinetic energy) plus its friction band."""
    sim = node._sim
    i = sim.names.index(joint)
    inertia = float(sim.physics.inertia_times(np.eye(sim.n)[i])[i])
    return abs(speed) * math.sqrt(inertia / sim._kp[i]) + band(node, joint)


def start(rclpy_context, executor, **params):
    from rclpy.parameter import Parameter

    from hyperarm_driver.mock_driver_node import MockDriver

    overrides = [Parameter(k, value=v) for k, v in params.items()]
    node = MockDriver(context=rclpy_context, parameter_overrides=overrides)
    executor.add_node(node)
    return node


def test_topics_services_and_bad_input(rclpy_context, executor, wait_for):
    node = start(rclpy_context, executor, rate=200.0, diagnostics_period=0.2)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: len(p.states) > 20, 10.0, what="joint_states")
    msg = p.states[-1][1]
    assert list(msg.name) == ARM + ["gripper"]
    assert len(msg.position) == len(msg.velocity) == len(msg.effort) == 10
    stamps = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in p.states[-20:]]
    assert np.all(np.diff(stamps) > 0.0)

    def at(joint, value):
        return p.settled(joint, value, band(node, joint))

    p.send(["joint1"], [0.4])
    wait_for(lambda: at("joint1", 0.4), 10.0, what="joint1 at 0.4")
    for bad in ((["joint1"], [float("nan")]), (["joint1", "elbow"], [0.1, 0.2]),
                (["joint1"], [0.1, 0.2])):
        p.send(*bad)
    # clamped to the upper limit (joint9: joint3 there would fold link3 onto link1)
    p.send(["joint9"], [99.0])
    # (MuJoCo's joint range stops the true joint, the encoders' plus the hidden offset: a
    # positive offset leaves the encoders that much short of the limit)
    wait_for(lambda: p.settled("joint9", 2.617993878,
                               band(node, "joint9") + abs(node._sim.offset[8])),
             10.0, what="joint9 at limit")
    assert at("joint1", 0.4)                      # the bad commands changed nothing

    off = p.call(contract.SET_TORQUE, wait_for, data=False)
    assert off.success and off.message == "torque off"
    wait_for(lambda: p.diag("mock_driver: joint1").get("torque") == "off", 5.0,
             what="torque off in diagnostics")
    assert p.call(contract.HOLD, wait_for).success
    r = p.call(contract.REBOOT, wait_for, joints=[])
    assert r.success and list(r.rebooted) == []
    r = p.call(contract.REBOOT, wait_for, joints=["joint42"])
    assert not r.success and "joint42" in r.message
    assert p.call(contract.SET_TORQUE, wait_for, data=True).success
    bus = p.diag("mock_driver: bus")
    assert bus["connected"] == "True" and int(bus["cycles"]) > 0
    servo = p.diag("mock_driver: joint1")
    assert servo["id"] == "1" and servo["model"] == "MX-106" and servo["hardware_error"] == "none"


def test_effort_watchdog_and_torque_mode(rclpy_context, executor, wait_for):
    node = start(rclpy_context, executor, command_timeout=0.2, diagnostics_period=0.1)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: p.diag("mock_driver: joint2"), 10.0, what="diagnostics")
    p.send(["joint2"], effort=[0.0])              # no torque: joint 2 falls
    wait_for(lambda: p.diag("mock_driver: joint2")["mode"] == "current", 5.0,
             what="joint2 in current (torque) mode")
    wait_for(lambda: p.diag("mock_driver: joint2")["mode"] == "current_based_position", 5.0,
             what="the watchdog to switch joint2 back to (current-based) position")
    # the servo catches the falling joint like a spring (MuJoCo's: it swings a while) and
    # holds it still: 30 joint_states (0.3 s at the default 100 Hz) within its friction band
    wait_for(lambda: p.settled("joint2", p.position("joint2"), 2.0 * band(node, "joint2"), 30),
             10.0, what="joint2 held still")
    held = p.position("joint2")
    assert abs(held) > 0.01                       # it had fallen
    assert p.diag("mock_driver: joint2")["mode"] == "current_based_position"


def test_camera_detections_and_ground_truth(rclpy_context, executor, wait_for):
    start(rclpy_context, executor)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: len(p.detections) >= 3 and len(p.truth) >= 3, 10.0, what="detections")
    d, t = p.detections[-1], p.truth[-1]
    assert d.header.frame_id == t.header.frame_id == contract.CAMERA_FRAME
    assert list(d.names) == list(t.names) == ["block", "source_peg", "destination_peg"]
    dp = np.array([d.poses[0].position.x, d.poses[0].position.y, d.poses[0].position.z])
    tp = np.array([t.poses[0].position.x, t.poses[0].position.y, t.poses[0].position.z])
    assert 0.0 < np.linalg.norm(dp - tp) < 0.02   # noisy (2 mm per axis), but close
    assert tp[0] == pytest.approx(0.6 - (-0.185))  # the block 0.785 m below the camera


def test_sim_time_runs_faster_and_publishes_clock(rclpy_context, executor, wait_for):
    start(rclpy_context, executor, sim_speed=4.0)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: len(p.clock) > 10, 10.0, what="/clock")
    wall0, c0 = p.clock[-1]
    wait_for(lambda: p.clock[-1][0] - wall0 >= 1.0, 5.0, what="1 s of /clock")
    wall1, c1 = p.clock[-1]
    sim = (c1.clock.sec - c0.clock.sec) + 1e-9 * (c1.clock.nanosec - c0.clock.nanosec)
    ratio = sim / (wall1 - wall0)
    assert 1.5 < ratio <= 4.0 * 1.05              # faster than real time, at most sim_speed
    stamp = p.states[-1][1].header.stamp
    assert stamp.sec < 100                        # stamped with simulated time from 0


def test_rail_variant_homing(rclpy_context, executor, wait_for):
    node = start(rclpy_context, executor, variant="rail_arm", diagnostics_period=0.1)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: p.states, 10.0, what="joint_states")
    assert list(p.states[-1][1].name)[0] == "rail"
    p.send(["rail"], [0.3])                        # refused: not homed
    wait_for(lambda: p.diag("mock_driver: rail").get("rejected_setpoints") == "1", 5.0,
             what="the setpoint before homing rejected")
    assert p.diag("mock_driver: rail")["homed"] == "false"
    # arm + rail before homing, as the Dynamixel + PMAC pair: the rail's part refused, the
    # arm's applied (docs/architecture.md)
    p.send(["rail", "joint1"], [0.3, 0.2])
    wait_for(lambda: p.diag("mock_driver: rail").get("rejected_setpoints") == "2", 5.0,
             what="the rail's part rejected")
    wait_for(lambda: p.settled("joint1", 0.2, band(node, "joint1")), 10.0,
             what="joint1 at 0.2 rad")
    # the rail did not move: its loop holds it against the arm's reaction within the
    # PMAC's in-position window (0.1 mm, diagnostics' in_position)
    assert abs(p.position("rail")) < 1e-4
    r = p.call(contract.RAIL_HOME, wait_for)
    assert r.success
    wait_for(lambda: p.diag("mock_driver: rail").get("homed") == "true", 5.0, what="homed")
    assert abs(p.position("rail")) < 1e-4       # homed: at 0 m within that window
    p.send(["rail", "joint1"], [0.3, 0.0], [0.0, 0.0])    # efforts of 0 include the rail
    wait_for(lambda: abs(p.position("rail") - 0.3) < 1e-6, 5.0, what="rail at 0.3 m")
    assert int(p.diag("mock_driver: rail")["rejected_setpoints"]) == 2


def test_rail_services_own_the_rail_and_arm_services_the_servos(rclpy_context, executor,
                                                                 wait_for):
    """One owner per service on rail_arm: set_torque / hold / reboot act on the arm and the
    gripper, rail/set_torque / rail/hold / rail/home on the rail."""
    start(rclpy_context, executor, variant="rail_arm", diagnostics_period=0.1)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: p.diag("mock_driver: rail") and p.diag("mock_driver: joint2"), 10.0,
             what="diagnostics")
    assert p.call(contract.RAIL_SET_TORQUE, wait_for, data=False).success
    wait_for(lambda: p.diag("mock_driver: rail").get("amp_enabled") == "false", 5.0,
             what="rail amplifier off")
    assert p.diag("mock_driver: joint2")["torque"] == "on"
    assert not p.call(contract.RAIL_HOME, wait_for).success      # amplifier off
    assert not p.call(contract.RAIL_HOLD, wait_for).success
    assert p.call(contract.RAIL_SET_TORQUE, wait_for, data=True).success
    assert p.call(contract.SET_TORQUE, wait_for, data=False).success
    wait_for(lambda: p.diag("mock_driver: joint2").get("torque") == "off", 5.0,
             what="arm torque off")
    assert p.diag("mock_driver: rail")["amp_enabled"] == "true"   # the rail's own
    assert p.call(contract.RAIL_HOME, wait_for).success
    wait_for(lambda: p.diag("mock_driver: rail").get("homed") == "true", 5.0, what="homed")
    p.send(["rail"], [0.2])
    wait_for(lambda: 0.01 < p.position("rail") < 0.19, 5.0, what="rail moving")
    assert p.call(contract.RAIL_HOLD, wait_for).success
    stopped = p.position("rail")
    time.sleep(0.5)
    assert abs(p.position("rail") - stopped) < 0.02 and p.position("rail") < 0.19
    r = p.call(contract.REBOOT, wait_for, joints=["rail"])
    assert not r.success and "rail/" in r.message


def test_true_tool_wrench_is_published_at_tool0(rclpy_context, executor, wait_for):
    from geometry_msgs.msg import WrenchStamped

    start(rclpy_context, executor)
    p = Probe(rclpy_context, executor)
    got: list = []
    p.node.create_subscription(WrenchStamped, contract.TOOL_WRENCH_TRUTH, got.append,
                               qos_for(contract.TOOL_WRENCH_TRUTH))
    wait_for(lambda: len(got) > 5, 10.0, what="debug/tool_wrench_truth")
    assert got[-1].header.frame_id == contract.TOOL_FRAME
    w = got[-1].wrench
    assert [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z] == [0.0] * 6


@pytest.mark.parametrize("params, message", [
    ({"workcell_file": "/nonexistent/workcell.yaml"}, "cannot read work-cell file"),
    ({"rate": 0.0}, "parameter rate=0.0 not within 1..1000"),
    ({"rate": "fast"}, "parameter rate must be a number, got 'fast'"),
    ({"command_timeout": float("nan")}, "parameter command_timeout=nan must be finite"),
    ({"sim_speed": -1.0}, "parameter sim_speed=-1.0 must be 0 (real time) or within 0.1..100"),
    ({"shutdown_torque": "drop"}, "parameter shutdown_torque='drop' not one of hold, release"),
    ({"torque_on_start": 1}, "parameter torque_on_start must be a bool"),
    ({"variant": "tripod"}, "unknown variant 'tripod'"),
])
def test_bad_parameters_stop_with_a_clear_message(rclpy_context, params, message):
    from rclpy.parameter import Parameter

    from hyperarm_driver.mock_driver_node import MockDriver

    with pytest.raises(SystemExit) as err:
        MockDriver(context=rclpy_context,
                   parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    assert message in str(err.value)


def test_pick_through_ros_topics(rclpy_context, executor, wait_for, tmp_path):
    """Drive a grasp through joint_command only (on sim time, 4x): the work cell reports the
    block held and the camera's ground truth shows it lifted with the tool. (The packaged
    cell without its repeatability, seeded: the blind IK goals with a hidden offset of a
    few mm would put a pad on the table or beside the block, as on the real arm.)"""
    import yaml

    from hyperarm_description.model import load_description
    from hyperarm_driver.mock.config import default_workcell_path, load_mock_config
    from hyperarm_driver.mock.joint_sim import JointSim
    from hyperarm_driver.mock.scenario import tool_down_ik

    raw = yaml.safe_load(default_workcell_path().read_text())
    raw["imperfections"].update(repeatability=0.0, seed=1)
    cell = tmp_path / "workcell.yaml"
    cell.write_text(yaml.safe_dump(raw))
    node = start(rclpy_context, executor, sim_speed=4.0, diagnostics_period=0.2,
                 workcell_file=str(cell))
    p = Probe(rclpy_context, executor)
    cfg = load_mock_config(cell)
    planner = JointSim(load_description(), cfg)        # only for its IK helper
    w = cfg.world
    src, half = w.peg("source"), w.block.size[2] / 2.0
    above = [*src.xy, w.table_height + src.height + half + 0.03]
    at_block = [*src.xy, w.table_height + half]
    q_above = tool_down_ik(planner, above)
    q_block = tool_down_ik(planner, at_block, q_above)

    def goto(q, gripper=None, effort=None):
        names, pos = list(ARM), list(q)
        if gripper is not None:
            names.append("gripper")
            pos.append(gripper)
        eff = [] if effort is None else [100.0] * 9 + [effort]   # 100: clamped to stall
        p.send(names, pos, eff)
        # (within the servos' friction bands: MuJoCo's)
        wait_for(lambda: all(abs(p.position(n) - v) <= max(band(node, n), 1e-3)
                             for n, v in zip(ARM, q)), 20.0, what="the arm at its goal")

    goto(q_above, gripper=1.3)
    wait_for(lambda: abs(p.position("gripper") - 1.3) <= max(band(node, "gripper"), 1e-3),
             10.0, what="gripper open")
    goto(q_block)
    p.send(["gripper"], [0.0], [0.6])
    wait_for(lambda: p.diag("mock_driver: work_cell").get("block_state") == "held", 10.0,
             what="the block held")
    z_before = p.truth[-1].poses[0].position.x          # camera x points down
    goto(q_above)
    wait_for(lambda: p.truth[-1].poses[0].position.x < z_before - 0.02, 10.0,
             what="the block lifted (seen by the camera)")
    assert p.diag("mock_driver: work_cell")["block_state"] == "held"


def test_hold_stops_the_arm_and_leaves_a_closing_gripper_its_goal(rclpy_context, executor,
                                                                   wait_for):
    """`hold`, as the Dynamixel driver does it: every arm joint stops where it is; a
    position-controlled gripper keeps its goal and limit (held where it is, a gripper
    squeezing a block would stop squeezing and drop it); an effort-controlled one is held."""
    node = start(rclpy_context, executor, rate=200.0)
    p = Probe(rclpy_context, executor)
    wait_for(lambda: len(p.states) > 5, 10.0, what="joint_states")
    p.send(["gripper"], [1.2])
    opened = max(band(node, "gripper"), 1e-3)    # (its friction band: MuJoCo's servo)
    wait_for(lambda: abs(p.position("gripper") - 1.2) <= opened, 10.0, what="gripper open")
    p.send(["joint1", "gripper"], [1.5, 0.0], [0.0, 0.3])     # both on their way
    wait_for(lambda: p.position("joint1") > 0.1 and p.position("gripper") < 1.1, 5.0,
             what="joint1 and the gripper moving")
    assert p.call(contract.HOLD, wait_for).success
    held = node._sim.goal[0]                      # where the hold stopped its reference
    wait_for(lambda: p.position("gripper") < 0.01, 10.0, what="the gripper closing on")
    # it stops short of its goal, within the swing its servo's spring allows from the
    # speed it had (at most the fastest seen: it slows down after the hold)
    speed = max(abs(m.velocity[list(m.name).index("joint1")]) for _, m in p.states)
    assert held < 1.0 and p.position("joint1") < 1.0
    assert abs(p.position("joint1") - held) <= swing(node, "joint1", speed)
    # effort-controlled, the gripper is held like a joint
    p.send(["gripper"], [1.2])
    wait_for(lambda: abs(p.position("gripper") - 1.2) <= opened, 10.0,
             what="gripper open again")

    def driven():       # the effort streamed (as a controller does: the watchdog's 0.5 s)
        p.send(["gripper"], effort=[-0.2])
        return p.position("gripper") < 1.1
    wait_for(driven, 5.0, what="the gripper driven by its effort")
    assert p.call(contract.HOLD, wait_for).success
    time.sleep(0.1)
    stopped = p.position("gripper")
    time.sleep(0.5)
    assert abs(p.position("gripper") - stopped) < 0.02 and stopped > 0.3
