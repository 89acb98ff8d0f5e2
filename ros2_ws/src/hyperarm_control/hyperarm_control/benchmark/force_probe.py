"""A probe node for the force node's end-to-end tests (and the benchmark): it can play the
driver (publish joint_states, serve ``hold``), records joint_command, the wrench estimate,
the mock's ground truth and the diagnostics, and calls the force node's services."""
from __future__ import annotations

import threading
import time

import numpy as np
import pinocchio as pin

from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.qos import qos_for

from hyperarm_ik.kinematics import Kinematics


class ForceProbe:
    def __init__(self, rclpy_context, executor, wait_for, driver: bool = False,
                 names: list[str] | None = None) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import WrenchStamped
        from sensor_msgs.msg import JointState
        from std_srvs.srv import SetBool, Trigger

        from hyperarm_interfaces.msg import HybridGoal

        self.wait_for = wait_for
        self.node = rclpy.create_node("force_probe", namespace=contract.DEFAULT_NAMESPACE,
                                      context=rclpy_context)
        n = self.node
        self.lock = threading.Lock()
        self.commands: list[tuple[float, object]] = []
        self.states: list[tuple[float, object]] = []
        self.wrench: list[tuple[float, object]] = []
        self.wrench_base: list[tuple[float, object]] = []
        self.truth: list[tuple[float, object]] = []
        self.statuses: list[tuple[float, dict, str]] = []
        self.contact_force: list[tuple[float, np.ndarray]] = []
        self.hold_calls: list[float] = []
        self.block_state = ""
        self.last_published = 0.0
        self._js = JointState
        n.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                              qos_for(contract.JOINT_COMMAND))
        n.create_subscription(WrenchStamped, contract.EE_WRENCH, self._rec(self.wrench),
                              qos_for(contract.EE_WRENCH))
        n.create_subscription(WrenchStamped, contract.EE_WRENCH_BASE, self._rec(self.wrench_base),
                              qos_for(contract.EE_WRENCH_BASE))
        n.create_subscription(WrenchStamped, contract.TOOL_WRENCH_TRUTH, self._rec(self.truth),
                              qos_for(contract.EE_WRENCH))
        n.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag,
                              qos_for(contract.DIAGNOSTICS))
        self.goal_pub = n.create_publisher(HybridGoal, contract.HYBRID_GOAL,
                                           qos_for(contract.HYBRID_GOAL))
        self.cmd_pub = n.create_publisher(JointState, contract.JOINT_COMMAND,
                                          qos_for(contract.JOINT_COMMAND))
        self.enable_cli = n.create_client(SetBool, contract.HYBRID_ENABLE)
        self.tare_cli = n.create_client(Trigger, contract.HYBRID_TARE)
        self.compliance_cli = n.create_client(SetBool, contract.HYBRID_COMPLIANCE)
        self._setbool, self._trigger, self._goal_type = SetBool, Trigger, HybridGoal
        if driver:
            self.names = list(names or contract.ARM_JOINTS)
            self.state_pub = n.create_publisher(JointState, contract.JOINT_STATES,
                                                qos_for(contract.JOINT_STATES))
            n.create_service(Trigger, contract.HOLD, self._on_hold)
            self.driving = False
            self.q = np.zeros(len(self.names))
            # its own thread, not the executor's: recording 100 Hz commands must not delay
            # the states (the node would rightly call them stale)
            self._stop_drive = threading.Event()
            threading.Thread(target=self._drive_loop, name="probe-driver",
                             daemon=True).start()
        else:
            n.create_subscription(JointState, contract.JOINT_STATES, self._rec(self.states),
                                  qos_for(contract.JOINT_STATES))
        executor.add_node(n)

    # -- recording ------------------------------------------------------------------------
    def _rec(self, store):
        def cb(msg):
            with self.lock:
                store.append((time.monotonic(), msg))
        return cb

    def _on_command(self, msg) -> None:
        """Only the force node's commands (exactly the arm joints): the probe's own gripper
        and arm moves, or a stray process on the domain, are not recorded."""
        if list(msg.name) == list(contract.ARM_JOINTS) and not self._own(msg):
            with self.lock:
                self.commands.append((time.monotonic(), msg))

    def _own(self, msg) -> bool:
        return msg.header.frame_id == "force_probe"

    def _on_diag(self, msg) -> None:
        now = time.monotonic()
        with self.lock:
            for s in msg.status:
                values = {kv.key: kv.value for kv in s.values}
                if s.name == "hybrid_force":
                    stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                    self.statuses.append((now, values, s.message, stamp))
                elif s.name == "mock_driver: work_cell" and "contact_force_N" in values:
                    self.contact_force.append(
                        (now, np.array([float(v) for v in values["contact_force_N"].split()])))
                    self.block_state = values.get("block_state", "")

    def _drive_loop(self) -> None:
        next_t = time.monotonic()
        while not self._stop_drive.is_set():
            if self.driving:
                try:
                    self.publish_state(self.q)
                except Exception:   # noqa: BLE001 - the context is gone: the test ended
                    return
            next_t += 0.01
            self._stop_drive.wait(max(next_t - time.monotonic(), 0.0))

    def close(self) -> None:
        """Stop the driver thread (if any)."""
        if hasattr(self, "_stop_drive"):
            self._stop_drive.set()

    def _on_hold(self, req, res):
        self.hold_calls.append(time.monotonic())
        res.success, res.message = True, "held (probe)"
        return res

    def mode(self) -> str | None:
        with self.lock:
            return self.statuses[-1][1]["mode"] if self.statuses else None

    def last_state(self):
        with self.lock:
            return self.states[-1][1] if self.states else None

    # -- actions --------------------------------------------------------------------------
    def call(self, client, request, timeout: float = 10.0):
        self.wait_for(client.service_is_ready, 20.0, what=f"service {client.srv_name}")
        fut = client.call_async(request)
        self.wait_for(fut.done, timeout, what=f"answer of {client.srv_name}")
        return fut.result()

    def enable(self, on: bool = True):
        return self.call(self.enable_cli, self._setbool.Request(data=on))

    def compliance(self, on: bool):
        return self.call(self.compliance_cli, self._setbool.Request(data=on))

    def tare(self):
        return self.call(self.tare_cli, self._trigger.Request())

    def send_goal(self, position, rotation, stiffness, force_axes=(False,) * 6,
                  wrench=(0.0,) * 6, frame: str = "base_link", quat=None,
                  age: float = 0.0) -> None:
        """Publish a hybrid goal stamped now - ``age`` (s) on the probe's clock."""
        from rclpy.duration import Duration
        g = self._goal_type()
        g.header.frame_id = frame
        g.header.stamp = (self.node.get_clock().now()
                          - Duration(nanoseconds=int(age * 1e9))).to_msg()
        g.pose.position.x, g.pose.position.y, g.pose.position.z = (float(v) for v in position)
        if quat is None:
            qq = pin.Quaternion(np.asarray(rotation, dtype=float))
            quat = (qq.x, qq.y, qq.z, qq.w)
        o = g.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in quat)
        g.stiffness = [float(v) for v in stiffness]
        g.force_controlled = [bool(v) for v in force_axes]
        f, t = g.wrench.force, g.wrench.torque
        f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in wrench)
        self.goal_pub.publish(g)

    def publish_state(self, q, dq=None, effort=None, names=None, age: float = 0.0) -> None:
        """Publish a joint state stamped now - ``age`` (s) on the probe's clock."""
        from rclpy.duration import Duration
        msg = self._js()
        msg.header.stamp = (self.node.get_clock().now()
                            - Duration(nanoseconds=int(age * 1e9))).to_msg()
        msg.name = list(names or self.names)
        msg.position = [float(v) for v in q]
        msg.velocity = [float(v) for v in (dq if dq is not None else np.zeros(len(q)))]
        msg.effort = [float(v) for v in (effort if effort is not None else np.zeros(len(q)))]
        self.state_pub.publish(msg)
        self.last_published = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    def command(self, names, positions, efforts=()) -> None:
        msg = self._js()
        msg.header.frame_id = "force_probe"      # tells the probe's own commands apart
        msg.name = list(names)
        msg.position = [float(v) for v in positions]
        msg.effort = [float(v) for v in efforts]
        self.cmd_pub.publish(msg)

    def joints(self, names) -> np.ndarray | None:
        msg = self.last_state()
        if msg is None:
            return None
        index = {n: i for i, n in enumerate(msg.name)}
        if not all(n in index for n in names):
            return None
        return np.array([msg.position[index[n]] for n in names])


class MockArm:
    """Joint-space moves of the mock through joint_command (before the force node is
    enabled), with the mock's small IK for a tool pointing down."""

    def __init__(self, probe: ForceProbe, wait_for) -> None:
        from hyperarm_driver.mock.joint_sim import JointSim

        self.probe, self.wait_for = probe, wait_for
        self.desc = load_description()
        self.kin = Kinematics(self.desc)
        self.sim = JointSim(self.desc)     # only for its model and limits (IK)
        self.arm = list(self.desc.arm_joint_names)
        self.q = np.zeros(9)

    def q_now(self) -> np.ndarray:
        box = []
        self.wait_for(lambda: box.append(self.probe.joints(self.arm)) or box[-1] is not None,
                      20.0, what="joint_states")
        return box[-1]

    def move(self, xyz, timeout: float = 6.0) -> np.ndarray:
        from hyperarm_driver.mock.scenario import tool_down_ik

        self.q = tool_down_ik(self.sim, xyz, self.q)
        self.probe.command(self.arm, self.q)
        self.wait_for(lambda: np.abs(self.q_now() - self.q).max() < 2e-3, timeout,
                      what=f"arm at {list(xyz)}")
        return self.q

    def grip(self, angle: float, effort: float | None = None, wait: bool = True) -> None:
        self.probe.command(["gripper"], [angle], [effort] if effort is not None else [])
        if wait:
            self.wait_for(lambda: (self.probe.joints(["gripper"]) is not None and
                                   abs(self.probe.joints(["gripper"])[0] - angle) < 0.05),
                          5.0, what=f"gripper at {angle}")

    def tool(self) -> np.ndarray:
        return self.kin.forward(self.q_now())


def excursion(probe: ForceProbe, arm: MockArm, p0: np.ndarray, action,
              seconds: float = 0.6) -> float:
    """Largest distance (m) of the tool (FK of the measured joints) from ``p0`` during
    ``seconds`` after ``action()``."""
    with probe.lock:
        n = len(probe.states)
    action()
    time.sleep(seconds)
    with probe.lock:
        states = [m for _, m in probe.states[n:]]
    idx = [list(states[0].name).index(j) for j in arm.arm]
    xs = np.array([arm.kin.forward(np.array(m.position)[idx])[:3, 3] for m in states])
    return float(np.linalg.norm(xs - p0, axis=1).max())


def step_response(probe: ForceProbe, arm: MockArm, step=(0.0, 0.02, 0.0),
                  stiffness=(800.0, 800.0, 800.0, 20.0, 20.0, 20.0), settle: float = 1.0,
                  duration: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Enabled at the present pose: hold ``settle`` s, then step the goal by ``step`` (m,
    every axis position-controlled) and record ``duration`` s. Returns (t s from the step,
    tool positions (N, 3) from the FK of the measured joints, the goal position)."""
    t = arm.tool()
    p0, r = t[:3, 3].copy(), t[:3, :3].copy()
    probe.send_goal(p0, r, stiffness)
    time.sleep(settle)
    goal = p0 + np.asarray(step)
    with probe.lock:
        n0 = len(probe.states)
    t0 = time.monotonic()
    probe.send_goal(goal, r, stiffness)
    time.sleep(duration)
    with probe.lock:
        states = probe.states[n0:]
    idx = [list(states[0][1].name).index(n) for n in arm.arm]
    ts = np.array([tt - t0 for tt, _ in states])
    xs = np.array([arm.kin.forward(np.array(m.position)[idx])[:3, 3] for _, m in states])
    return ts, xs, goal


def mean_force(samples, since: float) -> np.ndarray:
    """Mean force (N, 3) of WrenchStamped samples [(t, msg)] received after ``since``."""
    fs = [(m.wrench.force.x, m.wrench.force.y, m.wrench.force.z) for t, m in samples
          if t > since]
    return np.mean(fs, axis=0) if fs else np.full(3, np.nan)
