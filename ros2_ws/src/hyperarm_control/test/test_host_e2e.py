"""E2E: host_compensation holds tool0 in the world while its host moves (issue 15).

Installed executables over DDS: ``mock_driver`` (repeatability 0) and ``host_compensation``,
one launch per scenario:

- rail: on rail_arm the rail is homed (``rail/home``), the arm goes to a posture with tool0
  pointing down in front of its base, compensation is enabled at the present tool pose,
  then the mock's host motion ``rail_sweep`` moves the rail (someone else moves it: +-0.2 m
  at 0.2 m/s, 0.5 m/s^2 at the turnarounds), recorded from its start until it has been at
  +0.2 m and then at -0.2 m;
- reach (issue 24 item 1): on rail_arm, tool0 held 0.62 m ahead (near the stretched
  singularity) while the test streams rail setpoints 0.2 m away from it at 0.1 m/s and
  back: no arm command steps a joint further than its velocity limit times the states'
  period (the old node sent 0.47-3.65 rad in one command as the arm reached or left full
  stretch);
- 6-D sway: on the fixed arm the mock's host motion ``uav_sway`` (base_link sways 2 cm,
  heaves 1 cm and tilts 5 deg at 0.5 Hz in world), started with ``host_motion/enable``
  after compensation is enabled on ``host_pose``; recorded over the 2 s ramp and one full
  period; ``uav_sway_passive``, the same on the passive mount (the arm's reactions move its
  base), over the ramp and three periods.

Judged two ways: by FK of the measured joint states on the host pose (the rail joint, or the
``host_pose`` with the joint state's stamp), and by the mock's truth
(``debug/tool_pose_truth``): within 3 mm RMS and 8 mm max of the world pose and 2 degrees,
no unreachable report, every joint state the node got answered by a command and none
missing (the node's diagnostics against the test's count).
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from rclpy.duration import Duration
from hyperarm_description.qos import observer_qos, qos_for
from hyperarm_ik.kinematics import Kinematics, rotation_angle
from hyperarm_ik.ros_conversions import pose_to_matrix

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

ARM = list(contract.ARM_JOINTS)
# tool0 pointing down 0.2 m in front of the base (its wrist stays inside its reach while
# the base moves +-0.2 m; see test_host_core)
Q0 = [1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726]
# tool0 0.62 m ahead, 0.1 m up, 10 deg below forward (hyperarm_control.benchmark.host_sim.Q_REACH)
Q_REACH = [0.141, 0.134, -0.305, -0.071, 0.137, 0.3, 0.145, -0.19, -0.113]
def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def _matrix(msg: PoseStamped) -> np.ndarray:
    o = msg.pose.orientation
    n = math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w)
    o.x, o.y, o.z, o.w = o.x / n, o.y / n, o.z / n, o.w / n
    return pose_to_matrix(msg.pose)


def _nearest(poses: dict[int, np.ndarray], stamps) -> list:
    """For each joint-state stamp (ns), the host pose of the same mock tick: the newest one
    stamped at or before it (the mock publishes a host pose per simulation step, then the
    tick's joint state; in a catch-up tick of several steps the stamps are the wall-clock
    times of publication), None when none is within 20 ms."""
    keys = np.array(sorted(poses))
    out = []
    for s in stamps:
        i = int(np.searchsorted(keys, s, side="right")) - 1
        out.append(poses[int(keys[i])] if i >= 0 and s - int(keys[i]) < 20_000_000 else None)
    return out


def _errors(goal: np.ndarray, poses) -> tuple[float, float, float]:
    """RMS and max position error (m), max orientation error (deg) of poses vs goal."""
    p = np.array([np.linalg.norm(t[:3, 3] - goal[:3, 3]) for t in poses])
    o = max(rotation_angle(goal[:3, :3], t[:3, :3]) for t in poses)
    return float(np.sqrt(np.mean(p ** 2))), float(p.max()), math.degrees(o)


def _judge(what: str, goal: np.ndarray, poses, failed: list[str]) -> str:
    """The bounds' verdict on ``poses`` as text; a miss is also added to ``failed`` (the
    caller asserts after the whole summary is built: a failure shows every figure)."""
    rms, worst, deg = _errors(goal, poses)
    text = (f"{what}: {len(poses)} poses, RMS {rms * 1e3:.2f} mm, max {worst * 1e3:.2f} mm, "
            f"{deg:.3f} deg")
    if not (rms < 3e-3 and worst < 8e-3 and deg < 2.0):
        failed.append(what)
    return text


class Probe:
    """The test's node: joint states with arrival times, arm commands, reactions."""

    def __init__(self, context, executor) -> None:
        from rclpy.node import Node

        self.node = Node("host_e2e_probe", namespace=contract.DEFAULT_NAMESPACE,
                         context=context)
        self.lock = threading.Lock()
        self.states: list[tuple[float, dict]] = []
        self.state_stamps: list[int] = []
        self.commands: set[int] = set()     # the stamps of the arm commands (their state's)
        self.command_list: list[tuple[int, np.ndarray]] = []   # (stamp ns, arm positions)
        self.reactions: list[np.ndarray] = []
        self.truth: list[tuple[int, np.ndarray]] = []    # (stamp ns, tool0 in world)
        self.hosts: dict[int, np.ndarray] = {}            # stamp ns -> base_link in world
        self.homed = False
        self.diag: dict = {}
        self.diag_log: list[tuple[int, dict]] = []      # (stamp ns, values) of every one
        self.diag_time = 0.0
        self.diag_stamp = 0
        n = self.node
        n.create_subscription(JointState, contract.JOINT_STATES, self._on_state,
                              qos_for(contract.JOINT_STATES))
        # the test counts every command: it must not drop any itself
        n.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                              observer_qos(contract.JOINT_COMMAND))
        n.create_subscription(WrenchStamped, contract.BASE_REACTION, self._on_reaction,
                              qos_for(contract.BASE_REACTION))
        keep = qos_for(contract.HOST_POSE)
        keep.depth = 200      # every pose: the test matches them to joint states by stamp
        n.create_subscription(PoseStamped, contract.HOST_POSE, self._on_host, keep)
        n.create_subscription(PoseStamped, contract.TOOL_POSE_TRUTH, self._on_truth, keep)
        n.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag,
                              qos_for(contract.DIAGNOSTICS))
        self.cmd = n.create_publisher(JointState, contract.JOINT_COMMAND,
                                      qos_for(contract.JOINT_COMMAND))
        self.home = n.create_client(Trigger, contract.RAIL_HOME)
        self.enable = n.create_client(SetBool, contract.HOST_COMP_ENABLE)
        self.motion = n.create_client(SetBool, contract.HOST_MOTION_ENABLE)
        executor.add_node(n)

    def _on_state(self, msg: JointState) -> None:
        with self.lock:
            self.states.append((time.monotonic(), dict(zip(msg.name, msg.position))))
            self.state_stamps.append(_ns(msg.header.stamp))

    def _on_command(self, msg: JointState) -> None:
        if list(msg.name) == ARM:
            with self.lock:
                self.commands.add(_ns(msg.header.stamp))
                self.command_list.append((_ns(msg.header.stamp), np.array(msg.position)))

    def _on_host(self, msg: PoseStamped) -> None:
        with self.lock:
            self.hosts[_ns(msg.header.stamp)] = _matrix(msg)

    def _on_truth(self, msg: PoseStamped) -> None:
        with self.lock:
            self.truth.append((_ns(msg.header.stamp), _matrix(msg)))

    def _on_reaction(self, msg: WrenchStamped) -> None:
        f, t = msg.wrench.force, msg.wrench.torque
        with self.lock:
            self.reactions.append(np.array([f.x, f.y, f.z, t.x, t.y, t.z]))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name == "host_compensation":
                self.diag = {kv.key: kv.value for kv in st.values}
                self.diag_time = time.monotonic()
                self.diag_stamp = _ns(msg.header.stamp)
                with self.lock:
                    self.diag_log.append((self.diag_stamp, dict(self.diag)))
            if any(kv.key == "homed" and kv.value == "true" for kv in st.values):
                self.homed = True

    def latest(self) -> dict | None:
        with self.lock:
            return self.states[-1][1] if self.states else None

    def call(self, client, request, wait_for):
        wait_for(client.service_is_ready, 20.0, what=f"service {client.srv_name}")
        future = client.call_async(request)
        wait_for(future.done, 10.0, what=f"{client.srv_name} answer")
        return future.result()

    def send(self, names, positions) -> None:
        msg = JointState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.name = list(names)
        msg.position = [float(v) for v in positions]
        self.cmd.publish(msg)


def _start(launch, probe_args, variant: str, wait_for, **mock_params):
    # the mock on simulated time at 1x (one 10 ms step per tick, /clock): on a loaded machine
    # the simulation slows down instead of catching up in bursts of steps that all use one
    # arm command (what a real robot never does); the node runs on that clock
    # and in lockstep (lockstep_timeout): once host_compensation answers the states, each
    # step waits for its command (at most 0.2 s of wall time), so a scheduling stall of the
    # node on a loaded machine is not a rail motion uncompensated (docs/mock.md)
    mock = launch("hyperarm_driver", "mock_driver", params={
        "variant": variant, "repeatability": 0.0, "sim_speed": 1.0, "lockstep_timeout": 0.2,
        **mock_params})
    comp = launch("hyperarm_control", "host_compensation", params={
        "variant": variant, "diagnostics_period": 0.2, "use_sim_time": True})
    probe = Probe(*probe_args)
    wait_for(lambda: probe.latest() is not None, 30.0, what=f"{variant} joint_states")
    return mock, comp, probe


def _to_q0(probe: Probe, wait_for, rail: bool, q0=Q0) -> None:
    def at_q0():
        q = probe.latest()
        return max(abs(q[n] - v) for n, v in zip(ARM, q0)) < 2e-3 and (
            not rail or abs(q["rail"]) < 1e-3)

    probe.send(ARM, q0)
    wait_for(at_q0, 15.0, period=0.05, what="arm at the start posture")
    wait_for(lambda: len(probe.reactions) > 0 and len(probe.truth) > 0, 10.0,
             what="base_reaction and the tool truth")
    answers = []

    def enabled():         # the node may not have its first host pose yet (discovery)
        answers.append(probe.call(probe.enable, SetBool.Request(data=True), wait_for))
        return answers[-1].success

    wait_for(enabled, 15.0, period=0.2, what="host_compensation enabled")


def _window(probe: Probe, first_state: int):
    """(states, their stamps, truth poses, span s) from ``first_state`` on."""
    with probe.lock:
        states = [q for _t, q in probe.states[first_state:]]
        stamps = probe.state_stamps[first_state:]
        truth = [m for st, m in probe.truth if st >= stamps[0]]
        span = probe.states[-1][0] - probe.states[first_state][0]
    return states, stamps, truth, span


def _answered(probe: Probe, first_state: int, wait_for) -> str:
    """Every joint state the node got while enabled was answered by a command, and it got
    every one the mock sent. Compensation is disabled (its counts stop), then the node's
    counts (diagnostics) are compared with the test's count of the joint states stamped
    after the enable and at least 100 ms (simulated) before the disable (those had reached
    the node).
    The test cannot count the commands themselves: joint_command keeps depth 1, so a burst
    of them replaces one another in the node's writer, as it should for a setpoint."""
    with probe.lock:
        stop = probe.state_stamps[-1]          # the mock's clock (simulated time)
    res = probe.call(probe.enable, SetBool.Request(data=False), wait_for)
    assert res.success, res.message
    t = time.monotonic()
    wait_for(lambda: probe.diag_time > t + 0.05, 5.0,
             what="a host_compensation diagnostics after the disable")
    with probe.lock:
        d = dict(probe.diag)
        sent = sum(s <= stop - 100_000_000 for s in probe.state_stamps[first_state:])
    cycles, states = int(d["cycles"]), int(d["states"])
    text = (f"node answered {cycles}/{states} joint states (the test saw {sent} before; "
            f"its last reason: {d.get('reason', '?')})")
    assert d["enabled"] == "False" and cycles == states and states >= sent, text
    return text


def _check_clean(mock, comp) -> None:
    out = comp.output()
    assert "unreachable" not in out, out[-2000:]
    assert "Traceback" not in mock.output() + out


def test_tool_stays_in_the_world_while_the_rail_moves(launch, rclpy_context, executor,
                                                      wait_for):
    mock, comp, probe = _start(launch, (rclpy_context, executor), "rail_arm", wait_for,
                               host_motion="rail_sweep")
    kin = Kinematics(variant="rail_arm")
    res = probe.call(probe.home, Trigger.Request(), wait_for)
    assert res.success, res.message
    wait_for(lambda: probe.homed, 20.0, what="rail homed (mock diagnostics)")
    _to_q0(probe, wait_for, rail=True)

    def tool(q: dict) -> np.ndarray:
        return kin.forward(np.array([q[n] for n in kin.joint_names]))

    goal = tool(probe.latest())
    with probe.lock:
        first_state = len(probe.states)
        goal_truth = probe.truth[-1][1]
    res = probe.call(probe.motion, SetBool.Request(data=True), wait_for)
    assert res.success, res.message

    def swept():          # +0.2 m reached, then -0.2 m
        with probe.lock:
            rails = [q["rail"] for _t, q in probe.states[first_state:]]
        top = next((i for i, r in enumerate(rails) if r > 0.199), None)
        return top is not None and min(rails[top:]) < -0.199

    wait_for(swept, 15.0, period=0.05, what="the rail sweep to +0.2 m, then to -0.2 m")
    states, stamps, truth, span = _window(probe, first_state)
    rails = np.array([q["rail"] for q in states])
    failed: list[str] = []
    summary = "; ".join([
        _judge("FK of the joint states", goal, [tool(q) for q in states], failed),
        _judge("mock truth", goal_truth, truth, failed),
        _answered(probe, first_state, wait_for), f"{len(states) / span:.0f} Hz states",
        f"rail {rails.min():.4f}..{rails.max():.4f} m", f"node: {probe.diag}"])
    print(summary)
    assert not failed, summary
    assert rails.max() > 0.199 and rails.min() < -0.199, summary
    _check_clean(mock, comp)


# an ordinary posture (test_host_loop_sim's seed 0, the first): tool0 0.43 m from the base's
# axis; on the passive mount the previous node went 3.76 mm RMS, 15.9 mm max there (issue 24
# item 4: the mount's modes fed by the compensation; now the host pose's mount-mode filter)
Q_OTHER = [0.5, -0.84, -1.68, -1.77, 1.15, 1.51, 0.39, 0.84, 0.16]


@pytest.mark.parametrize("motion, seconds, q0", [("uav_sway", 4.2, Q0),
                                                 ("uav_sway_passive", 8.2, Q0),
                                                 ("uav_sway_passive", 8.2, Q_OTHER)],
                         ids=["uav_sway", "uav_sway_passive", "uav_sway_passive_other"])
def test_tool_stays_in_the_world_under_a_6d_sway(motion, seconds, q0, launch, rclpy_context,
                                                 executor, wait_for):
    mock, comp, probe = _start(launch, (rclpy_context, executor), "arm", wait_for,
                               host_motion=motion)
    kin = Kinematics(variant="arm")
    wait_for(lambda: len(probe.hosts) > 0, 10.0, what="host_pose")
    _to_q0(probe, wait_for, rail=False, q0=q0)
    with probe.lock:
        first_state = len(probe.states)
        rest = probe.hosts[max(probe.hosts)]      # the host at rest: its newest pose
        goal = rest @ kin.forward(np.array([probe.states[-1][1][n] for n in ARM]))
        goal_truth = probe.truth[-1][1]
    res = probe.call(probe.motion, SetBool.Request(data=True), wait_for)
    assert res.success, res.message
    t0 = time.monotonic()
    wait_for(lambda: time.monotonic() - t0 > seconds, seconds + 6.0, period=0.1,
             what=f"the 2 s ramp and {seconds - 2.0:.1f} s of sway")

    def judged():
        """The window so far, its states paired with the host pose of their tick, and how
        far the host moved (m) and tilted (rad) on those."""
        states, stamps, truth, span = _window(probe, first_state)
        with probe.lock:
            pairs = [(h, q) for h, q in zip(_nearest(probe.hosts, stamps), states)
                     if h is not None]
        sway = max((np.linalg.norm(h[:3, 3] - rest[:3, 3]) for h, _q in pairs), default=0.0)
        tilt = max((rotation_angle(rest[:3, :3], h[:3, :3]) for h, _q in pairs), default=0.0)
        return states, truth, span, pairs, sway, tilt

    # the motion runs on the mock's clock: a mock slowed by a loaded machine (a CI run: 27 Hz
    # states) needs longer than `seconds` of wall time for the whole sway; judged once it ran
    wait_for(lambda: (lambda w: w[4] > 0.019 and math.degrees(w[5]) > 4.9)(judged()), 20.0,
             period=0.2, what="the whole sway (19 mm, 4.9 deg) on the paired host poses")
    states, truth, span, pairs, sway, tilt = judged()
    assert len(pairs) >= 0.5 * len(states), (len(pairs), len(states))   # enough to judge
    poses = [h @ kin.forward(np.array([q[n] for n in ARM])) for h, q in pairs]
    failed: list[str] = []
    summary = "; ".join([
        _judge("FK of the joint states on host_pose", goal, poses, failed),
        _judge("mock truth", goal_truth, truth, failed),
        _answered(probe, first_state, wait_for), f"{len(states) / span:.0f} Hz states",
        f"{len(pairs)} of {len(states)} states paired with a host_pose",
        f"host moved {sway * 1e3:.1f} mm, tilted {math.degrees(tilt):.2f} deg",
        f"node: {probe.diag}"])
    print(summary)
    assert not failed, summary
    assert sway > 0.019 and math.degrees(tilt) > 4.9, summary      # the whole sway ran
    _check_clean(mock, comp)


def test_no_command_jumps_while_the_rail_takes_the_arm_to_full_stretch_and_back(
        launch, rclpy_context, executor, wait_for):
    """Issue 24 item 1 through the installed executables: tool0 held 0.62 m ahead, the rail
    streamed 0.2 m away at 0.1 m/s (simulated time) and back. Every pair of successive arm
    commands received differs by at most the joints' velocity limit (3 rad/s) times the
    difference of their stamps (the states' they answer)."""
    mock, comp, probe = _start(launch, (rclpy_context, executor), "rail_arm", wait_for)
    res = probe.call(probe.home, Trigger.Request(), wait_for)
    assert res.success, res.message
    wait_for(lambda: probe.homed, 20.0, what="rail homed (mock diagnostics)")
    _to_q0(probe, wait_for, rail=True, q0=Q_REACH)
    with probe.lock:
        first_state, t0 = len(probe.states), probe.state_stamps[-1]
        first_command = len(probe.command_list)
    seen = {"away": False}

    def stream() -> bool:               # one setpoint per call, on the mock's clock
        with probe.lock:
            t = (probe.state_stamps[-1] - t0) * 1e-9
            rail = probe.states[-1][1]["rail"]
        # 0.2 m away at 0.1 m/s, 0.5 s there, back at 0.1 m/s
        x = -0.1 * t if t < 2.0 else min(-0.2 + 0.1 * max(t - 2.5, 0.0), 0.0)
        probe.send(["rail"], [x])
        seen["away"] |= rail < -0.19
        return seen["away"] and t > 4.5 and rail > -0.005

    wait_for(stream, 60.0, period=0.02, what="the rail 0.2 m away and back")
    with probe.lock:
        cmds = probe.command_list[first_command:]
        rails = [q["rail"] for _t, q in probe.states[first_state:]]
        states = [q for _t, q in probe.states[first_state:]]
        stamps = np.array(probe.state_stamps[first_state:])
        diags = [(st, d) for st, d in probe.diag_log if st >= stamps[0]]
    # issue 24 item 5: the status follows the MEASURED tool: wherever the tool (FK of the
    # measured joints, rail included) was more than 10 mm off over the 100 ms before a
    # diagnostics message, that message does not say tracking (the old node did)
    kin = Kinematics(variant="rail_arm")
    goal = kin.forward(np.array([states[0][n] for n in kin.joint_names]))
    err = np.array([np.linalg.norm(kin.forward(np.array([q[n] for n in kin.joint_names]))
                                   [:3, 3] - goal[:3, 3]) for q in states])
    wrong = [(st, d["status"]) for st, d in diags
             if d["enabled"] == "True" and d["status"] == "tracking"
             and np.any(w := (stamps <= st) & (stamps > st - 100_000_000))
             and err[w].min() > 0.010]
    statuses = sorted({d["status"] for _st, d in diags})
    vmax = np.array([j.velocity for j in Kinematics(variant="arm").desc.joints])
    worst, where = 0.0, None
    for (s0, q0), (s1, q1) in zip(cmds, cmds[1:]):
        dt = (s1 - s0) * 1e-9
        ratio = float(np.max(np.abs(q1 - q0) / (vmax * dt))) if dt > 0 else math.inf
        if ratio > worst:
            worst, where = ratio, (float(np.abs(q1 - q0).max()), dt)
    summary = (f"{len(cmds)} commands; largest step / (velocity limit x period) {worst:.3f} "
               f"({where[0]:.4f} rad over {where[1] * 1e3:.1f} ms); rail "
               f"{min(rails):.3f}..{max(rails):.3f} m; tool error max {err.max() * 1e3:.1f} mm; "
               f"statuses {statuses}; 'tracking' while > 10 mm off: {wrong[:5]}; node: "
               f"{probe.diag}")
    print(summary)
    assert len(cmds) > 200 and min(rails) < -0.19, summary
    assert worst <= 1.0 + 1e-6, summary
    assert err.max() > 0.010 and len(diags) > 10, summary     # the tool was off: judged
    assert not wrong, summary
    assert "Traceback" not in mock.output() + comp.output()


def test_a_late_host_pose_moves_nothing_and_is_counted(launch, rclpy_context, executor,
                                                       wait_for):
    """Issue 24 item 3 through the installed host_compensation (fixed arm, host from
    host_pose): joint states and host poses at 100 Hz from the test, compensation enabled;
    then one host pose 0.2 s out of order and one stamped now - 2 s, each 3 cm off. The
    commands do not move the tool (the old node took each as the current host pose: ~6 mm),
    the diagnostics count them, the log says why."""
    comp = launch("hyperarm_control", "host_compensation", params={
        "variant": "arm", "diagnostics_period": 0.2, "stale_timeout": 1.0})
    probe = Probe(rclpy_context, executor)
    host = probe.node.create_publisher(PoseStamped, contract.HOST_POSE,
                                       qos_for(contract.HOST_POSE))
    states = probe.node.create_publisher(JointState, contract.JOINT_STATES,
                                         qos_for(contract.JOINT_STATES))
    kin = Kinematics(variant="arm")
    clock = probe.node.get_clock()

    last_good = []                             # the newest good host pose's stamp

    def tick(x: float = 0.0, age: float = 0.0, before_last: float | None = None) -> None:
        now = clock.now()
        msg = PoseStamped()
        msg.header.frame_id = contract.WORLD_FRAME
        # ``before_last``: stamped that long before the newest good one sent (out of order
        # whatever the load made of the time between ticks)
        stamp = now - Duration(seconds=age) if before_last is None else \
            last_good[-1] - Duration(seconds=before_last)
        msg.header.stamp = stamp.to_msg()
        if x == 0.0 and age == 0.0 and before_last is None:
            last_good.append(stamp)
        msg.pose.position.x = x
        msg.pose.orientation.w = 1.0
        host.publish(msg)
        st = JointState()
        st.header.stamp = now.to_msg()
        st.name, st.position = ARM, list(Q0)
        states.publish(st)

    def tool(q) -> np.ndarray:
        return kin.forward(np.asarray(q))[:3, 3]

    answers = []

    def enabled():
        tick()
        answers.append(probe.call(probe.enable, SetBool.Request(data=True), wait_for))
        return answers[-1].success

    wait_for(enabled, 20.0, period=0.1, what="host_compensation enabled")
    for _ in range(30):
        tick()
        time.sleep(0.01)
    wait_for(lambda: len(probe.command_list) > 10, 10.0, what="arm commands")
    with probe.lock:
        steady = probe.command_list[-1][1]
        first = len(probe.command_list)
    def counted(key: str) -> bool:
        """The node's diagnostics count a rejection ``key``; meanwhile joint_states only
        (host_pose keeps a history of 1: a good pose sent now would replace the bad one
        before a loaded node takes it; one CI run counted no out-of-order pose so)"""
        st = JointState()
        st.header.stamp = clock.now().to_msg()
        st.name, st.position = ARM, list(Q0)
        states.publish(st)
        with probe.lock:
            return int(probe.diag.get(key, 0)) >= 1

    # older than the newest used, 3 cm off: 0.2 s before the newest sent, so older than any
    # the node took lately (host_pose keeps 1: a loaded node skips poses; 30 ms before the
    # newest sent was not older than the newest it had taken, in two fresh-clone runs), and
    # sent first, well within max_message_age (0.5 s)
    tick(x=0.03, before_last=0.2)
    wait_for(lambda: counted("host_pose_rejected_out_of_order"), 2.0, period=0.01,
             what="the out-of-order host pose counted")
    tick(x=0.03, age=2.0)                      # late by 2 s, 3 cm off
    wait_for(lambda: counted("host_pose_rejected_stale"), 2.0, period=0.01,
             what="the late host pose counted")
    for _ in range(30):
        time.sleep(0.01)
        tick()
    t = time.monotonic()
    wait_for(lambda: probe.diag_time > t + 0.05, 5.0, what="diagnostics")
    with probe.lock:
        after = [q for _s, q in probe.command_list[first:]]
        d = dict(probe.diag)
    moved = max(float(np.linalg.norm(tool(q) - tool(steady))) for q in after)
    summary = f"{len(after)} commands after; tool moved {moved * 1e3:.3f} mm; node: {d}"
    print(summary)
    assert len(after) > 10, summary
    assert moved < 1e-4, summary
    assert int(d["host_pose_rejected_stale"]) >= 1, summary
    assert int(d["host_pose_rejected_out_of_order"]) >= 1, summary
    out = comp.output()
    assert "stamped 2.0" in out and "before the newest one used" in out, out[-2000:]
