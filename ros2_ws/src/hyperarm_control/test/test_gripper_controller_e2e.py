"""e2e: control_msgs/GripperCommand through the installed gripper_controller on the installed
mock_driver (issue 26), one set of processes, in turn:

1. open: succeeded, reached_goal, the measured position within goal_tolerance of fully open;
2. bad goals (NaN position, a position past the open limit, a negative max_effort): each
   aborted at once, reached_goal and stalled false, no gripper joint_command, nothing moves;
3. a close cancelled after 0.15 s (nothing between the fingers): canceled, the gripper
   holds where it was (one hold command, then silence);
4. a close preempted by an open: the close aborted, the open succeeds;
5. the block between the fingers: the set-up is the simplest honest one the mock allows.
   The mock's default cell has the block on the source peg; the test computes, without
   ROS, the arm posture putting tool0 (hand down) 5 cm above the block's centre and at it
   (``tool_down_ik`` of the mock's own ``scenario`` module, on the mock's model), and
   commands the arm there with plain ``joint_command`` (the mock's repeatability offsets off,
   ``repeatability:=0``, so the fingers meet the block as computed). Then a close (position
   0, max_effort 0.6 N·m) succeeds with stalled=true and reached_goal=false, the measured
   position on the block (~0.70 rad, far from 0) and the effort at the limit; the mock's
   work cell reports the block ``held``;
6. an open: reached_goal at fully open, the block released;
7. stale joint_states (the mock stopped with SIGSTOP during a goal): aborted.

Then, on the installed dynamixel_driver with its dxl_emulator: the same open and close,
the gripper servo blocked by the emulator's obstacle (stalled there with the grip effort).
"""
from __future__ import annotations

import math
import os
import signal
import time

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.model import load_description

pytestmark = [pytest.mark.e2e]

DESC = load_description(None, "arm")
G = DESC.gripper
ARM = [j.name for j in DESC.joints]
TOL = 0.01
SUCCEEDED, CANCELED, ABORTED = 4, 5, 6


def _block_postures() -> tuple[np.ndarray, np.ndarray]:
    """Arm postures with tool0 (hand down) 5 cm above the block's centre and at it."""
    from hyperarm_driver.mock.joint_sim import JointSim
    from hyperarm_driver.mock.scenario import tool_down_ik

    sim = JointSim(DESC)
    block = sim.world.block_pose(sim.tool_pose())[:3, 3]
    above = tool_down_ik(sim, block + np.array([0.0, 0.0, 0.05]))
    at = tool_down_ik(sim, block, above)
    return above, at


class Probe:
    def __init__(self, executor, context) -> None:
        import rclpy
        from control_msgs.action import GripperCommand
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.action import ActionClient
        from sensor_msgs.msg import JointState

        from hyperarm_description.qos import qos_for

        self.node = rclpy.create_node("gripper_probe", namespace=contract.DEFAULT_NAMESPACE,
                                      context=context)
        self.q: dict[str, float] = {}
        self.gripper_commands: list[tuple[float, float]] = []
        self.work_cell: dict[str, str] = {}
        self.node.create_subscription(JointState, contract.JOINT_STATES,
                                      lambda m: self.q.update(zip(m.name, m.position)),
                                      qos_for(contract.JOINT_STATES))
        self.node.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                      qos_for(contract.JOINT_COMMAND))
        self.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag,
                                      qos_for(contract.DIAGNOSTICS))
        self.pub = self.node.create_publisher(JointState, contract.JOINT_COMMAND,
                                              qos_for(contract.JOINT_COMMAND))
        self.action = GripperCommand
        self.client = ActionClient(self.node, GripperCommand, contract.GRIPPER_ACTION)
        executor.add_node(self.node)

    def _on_command(self, msg) -> None:
        if G.name in msg.name:
            i = list(msg.name).index(G.name)
            self.gripper_commands.append((msg.position[i], msg.effort[i] if msg.effort else 0))

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            if st.name == "mock_driver: work_cell":
                self.work_cell = {kv.key: kv.value for kv in st.values}

    def send(self, position: float, max_effort: float, wait_for):
        goal = self.action.Goal()
        goal.command.position, goal.command.max_effort = float(position), float(max_effort)
        from hyperarm_control.client import in_executor

        fut = in_executor(self.node, lambda: self.client.send_goal_async(goal))
        wait_for(fut.done, 5.0, what="goal accepted")
        handle = fut.result()
        assert handle.accepted
        return handle, in_executor(self.node, handle.get_result_async)

    def run(self, position: float, max_effort: float, wait_for, timeout: float = 10.0):
        _handle, res = self.send(position, max_effort, wait_for)
        wait_for(res.done, timeout, what=f"the result of a goal to {position}")
        return res.result().status, res.result().result

    def move_arm(self, q: np.ndarray, wait_for) -> None:
        from sensor_msgs.msg import JointState

        self.pub.publish(JointState(name=ARM, position=[float(x) for x in q]))
        wait_for(lambda: max(abs(self.q[n] - x) for n, x in zip(ARM, q)) < 2e-3, 15.0,
                 what="the arm at its posture")


def test_gripper_command_on_the_mock(launch, executor, rclpy_context, wait_for):
    above, at = _block_postures()
    t0 = time.monotonic()
    mock = launch("hyperarm_driver", "mock_driver", params={"repeatability": 0.0})
    ctl = launch("hyperarm_control", "gripper_controller",
                 params={"stall_timeout": 0.5, "goal_tolerance": TOL})
    p = Probe(executor, rclpy_context)
    wait_for(lambda: p.client.server_is_ready() and G.name in p.q, 60.0,
             what="gripper_controller's action server")

    # 1. open fully
    status, r = p.run(G.upper, 0.0, wait_for)
    assert status == SUCCEEDED and r.reached_goal and not r.stalled, r
    assert abs(r.position - G.upper) <= TOL and abs(p.q[G.name] - G.upper) <= 2 * TOL

    # 2. bad goals: aborted at once, nothing sent, nothing moves
    n = len(p.gripper_commands)
    for pos, eff in ((math.nan, 0.0), (G.upper + 0.1, 0.0), (0.5, -1.0)):
        status, r = p.run(pos, eff, wait_for, 3.0)
        assert status == ABORTED and not r.reached_goal and not r.stalled
    time.sleep(0.3)
    assert len(p.gripper_commands) == n
    assert abs(p.q[G.name] - G.upper) <= 2 * TOL
    out = ctl.output()
    assert "is not a finite number" in out and "outside gripper's limits" in out \
        and "is negative" in out

    # 3. cancel mid-close: holds where it is
    handle, res = p.send(0.0, 0.0, wait_for)
    time.sleep(0.15)
    from hyperarm_control.client import in_executor

    cancel = in_executor(p.node, handle.cancel_goal_async)
    wait_for(res.done, 5.0, what="the cancelled goal's end")
    assert res.result().status == CANCELED
    time.sleep(0.3)          # the servo brakes (its profile) and returns to the hold
    hold, n = p.gripper_commands[-1][0], len(p.gripper_commands)
    assert TOL < hold < G.upper - TOL, hold        # stopped on the way
    assert cancel.done()
    time.sleep(0.5)
    assert abs(p.q[G.name] - hold) < 0.02 and len(p.gripper_commands) == n   # silent

    # 4. preemption: a close replaced by an open
    _h1, res1 = p.send(0.0, 0.0, wait_for)
    status, r = p.run(G.upper, 0.0, wait_for)
    wait_for(res1.done, 5.0, what="the preempted goal's end")
    assert res1.result().status == ABORTED
    assert status == SUCCEEDED and r.reached_goal

    # 5. the block between the fingers: close on it
    p.move_arm(above, wait_for)
    p.move_arm(at, wait_for)
    contact = G.lower + 0.04 / G.max_opening * (G.upper - G.lower)   # the 4 cm block
    status, r = p.run(0.0, 0.6, wait_for)
    assert status == SUCCEEDED and r.stalled and not r.reached_goal, r
    assert abs(r.position - contact) < 0.05 and r.position > 0.5    # short of 0: the block
    assert r.effort == pytest.approx(-0.6, abs=0.1)
    wait_for(lambda: p.work_cell.get("block_state") == "held", 5.0, what="block held")

    # 6. open: fully open, the block released
    status, r = p.run(G.upper, 0.0, wait_for)
    assert status == SUCCEEDED and r.reached_goal and not r.stalled
    assert abs(r.position - G.upper) <= TOL
    wait_for(lambda: p.work_cell.get("block_state") not in (None, "held"), 5.0,
             what="block released")

    # 7. stale joint_states: the mock stopped during a goal
    _h, res = p.send(1.0, 0.0, wait_for)
    os.kill(mock.proc.pid, signal.SIGSTOP)
    try:
        wait_for(res.done, 5.0, what="the goal aborted on stale joint_states")
    finally:
        os.kill(mock.proc.pid, signal.SIGCONT)
    assert res.result().status == ABORTED
    wait_for(lambda: "older than max_state_age" in ctl.output(), 5.0, what="the stale log")
    assert time.monotonic() - t0 < 45.0


def test_gripper_command_on_the_dynamixel_emulator(launch, executor, rclpy_context, wait_for,
                                                   tmp_path):
    """The installed dynamixel_driver on its installed dxl_emulator (started as
    test_dxl_e2e.py does), the gripper servo (ID 10) blocked by the emulator's obstacle at
    0.4 rad as an object would block it: an open reaches fully open; a close stalls on the
    obstacle with the grip current's effort (stalled=true, reached_goal=false); with the
    obstacle gone an open reaches the goal again."""
    from hyperarm_driver.dynamixel.config import bus_config_from_description
    from hyperarm_driver.dynamixel.emulator import EmulatorControl

    grip = bus_config_from_description(DESC).joints[-1]
    link, ctl_path = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl_path)

    def connect():
        try:
            return EmulatorControl(ctl_path)
        except (FileNotFoundError, ConnectionRefusedError):
            return None

    control = wait_for(connect, 20.0, what="emulator control socket")
    try:
        launch("hyperarm_driver", "dynamixel_driver",
               params={"port": link, "torque_on_start": True})
        launch("hyperarm_control", "gripper_controller", params={"stall_timeout": 0.5})
        p = Probe(executor, rclpy_context)
        wait_for(lambda: p.client.server_is_ready() and G.name in p.q, 60.0,
                 what="gripper_controller's action server")
        wait_for(lambda: control("state")["servos"]["10"]["torque_enable"] == 1, 20.0,
                 what="torque on")
        status, r = p.run(1.2, 0.0, wait_for)
        assert status == SUCCEEDED and r.reached_goal and abs(r.position - 1.2) <= TOL, r
        control("obstacle", id=10, position=grip.rad_to_ticks_float(0.4))
        status, r = p.run(0.0, 0.0, wait_for)
        assert status == SUCCEEDED and r.stalled and not r.reached_goal, r
        assert abs(r.position - 0.4) < 0.02
        assert r.effort == pytest.approx(-G.grip_effort, rel=0.1)
        control("obstacle", id=10, position=None)
        status, r = p.run(G.upper, 0.0, wait_for)
        assert status == SUCCEEDED and r.reached_goal and abs(r.position - G.upper) <= TOL
    finally:
        control.close()
