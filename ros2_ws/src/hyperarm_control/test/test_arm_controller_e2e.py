"""e2e: the installed arm_controller with the installed mock_driver. A JointTrajectory on
arm_controller/joint_trajectory takes the arm to its last point (measured on joint_states)
and succeeds; every joint_command it sends stays within the limits and within one
velocity-limit step of the previous one; a trajectory with a wrong joint set or too fast is
rejected with its code in the log and the diagnostics, nothing sent; a new trajectory
preempts the running one and an empty one stops it, with no jump; SIGTERM exits 0."""
from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from hyperarm_description.model import load_description

pytestmark = [pytest.mark.e2e]

DESC = load_description(None, "arm")
NAMES = [j.name for j in DESC.joints]
VMAX = np.array([j.velocity for j in DESC.joints])
LO = np.array([j.lower for j in DESC.joints])
HI = np.array([j.upper for j in DESC.joints])
RATE = 100.0


def _trajectory(names, points):
    from builtin_interfaces.msg import Duration
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    msg = JointTrajectory()
    msg.joint_names = list(names)
    for t, q in points:
        pt = JointTrajectoryPoint()
        pt.positions = [float(x) for x in q]
        pt.time_from_start = Duration(sec=int(t), nanosec=int(round((t % 1) * 1e9)))
        msg.points.append(pt)
    return msg


def test_follows_rejects_preempts_and_stops(launch, rclpy_context, executor, wait_for):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from trajectory_msgs.msg import JointTrajectory

    from hyperarm_description import contract
    from hyperarm_description.qos import observer_qos, qos_for

    launch("hyperarm_driver", "mock_driver")
    ctl = launch("hyperarm_control", "arm_controller",
                 params={"rate": RATE, "diagnostics_period": 0.2})
    probe = rclpy.create_node("arm_controller_probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    executor.add_node(probe)
    states, commands, diags = {}, [], []

    def on_state(m):
        states.update(zip(m.name, m.position))
    probe.create_subscription(JointState, contract.JOINT_STATES, on_state,
                              qos_for(contract.JOINT_STATES))
    probe.create_subscription(JointState, contract.JOINT_COMMAND,
                              lambda m: commands.append(dict(zip(m.name, m.position))),
                              observer_qos(contract.JOINT_COMMAND))
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: diags.extend(s for s in m.status
                                                     if s.name == "arm_controller"),
                              qos_for(contract.DIAGNOSTICS))
    pub = probe.create_publisher(JointTrajectory, "arm_controller/joint_trajectory", 10)
    # the controller has the arm's joint_states too once it serves its action
    wait_for(lambda: pub.get_subscription_count() and all(n in states for n in NAMES)
             and diags and "joint_states of every joint received" in ctl.output(), 60.0,
             what=lambda: f"arm_controller up\n{ctl.output()}")

    def q_now():
        return np.array([states[n] for n in NAMES])

    def last_diag():
        return {kv.key: kv.value for kv in diags[-1].values}

    # 1. rejected goals: a joint missing (-2), a move far too fast (-1); nothing is sent
    pub.publish(_trajectory(NAMES[:-1], [(1.0, np.zeros(8))]))
    pub.publish(_trajectory(NAMES, [(0.05, q_now() + 0.5)]))
    wait_for(lambda: last_diag().get("rejected") == "2", 10.0, what="two rejections")
    assert "rejected (-1)" in last_diag()["last_result"] and "velocity" in \
        last_diag()["last_result"]
    wait_for(lambda: "rejected (-2): joint_names: missing joint9" in ctl.output(), 5.0,
             what="the log line")
    assert commands == []

    # 2. a trajectory through two points: reached, succeeded
    q0 = q_now()
    mid, goal = q0 + 0.15, q0 + np.where(np.arange(9) % 2, -0.2, 0.25)
    pub.publish(_trajectory(NAMES, [(1.0, mid), (2.0, goal)]))
    wait_for(lambda: last_diag().get("succeeded") == "1", 20.0,
             what=lambda: f"success\n{ctl.output()[-2000:]}")
    wait_for(lambda: np.max(np.abs(q_now() - goal)) < 0.03, 10.0, what="the arm at the goal")

    # 3. preempted half-way by another, then stopped by an empty one: no jump, it holds
    pub.publish(_trajectory(NAMES, [(3.0, q0)]))
    wait_for(lambda: np.max(np.abs(q_now() - goal)) > 0.05, 10.0, what="moving back")
    pub.publish(_trajectory(NAMES, [(2.0, q0 - 0.1)]))        # preempts
    wait_for(lambda: last_diag().get("accepted") == "3", 10.0, what="preemption")
    pub.publish(JointTrajectory(joint_names=NAMES))           # stops
    wait_for(lambda: last_diag().get("stopped") == "1", 10.0, what="stopped")
    wait_for(lambda: last_diag().get("commanding") == "false", 10.0, what="silent")
    n = len(commands)
    held = q_now()
    time.sleep(0.5)
    assert len(commands) == n                                  # silent while holding
    assert np.max(np.abs(q_now() - held)) < 0.01

    # the invariant over everything it sent
    cmds = np.array([[c[nm] for nm in NAMES] for c in commands])
    assert len(cmds) > 200
    assert np.all(cmds >= LO) and np.all(cmds <= HI)
    steps = np.abs(np.diff(cmds, axis=0))
    assert np.all(steps <= VMAX / RATE + 1e-9), steps.max(axis=0) * RATE / VMAX

    ctl.proc.send_signal(signal.SIGTERM)
    assert ctl.proc.wait(timeout=10.0) == 0, ctl.output()


def test_late_and_out_of_order_joint_states_are_not_used(launch, rclpy_context, executor,
                                                         wait_for):
    """joint_states stamped 2 s ago, or older than the newest used, are counted and not
    used: a trajectory starts from the fresh position, not from the late one."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.duration import Duration
    from sensor_msgs.msg import JointState
    from trajectory_msgs.msg import JointTrajectory

    from hyperarm_description import contract
    from hyperarm_description.qos import observer_qos, qos_for

    ctl = launch("hyperarm_control", "arm_controller", params={"diagnostics_period": 0.2})
    probe = rclpy.create_node("arm_controller_probe2", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    executor.add_node(probe)
    diags, commands = [], []
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: diags.extend(s for s in m.status
                                                     if s.name == "arm_controller"),
                              qos_for(contract.DIAGNOSTICS))
    probe.create_subscription(JointState, contract.JOINT_COMMAND,
                              lambda m: commands.append(list(m.position)),
                              observer_qos(contract.JOINT_COMMAND))
    states = probe.create_publisher(JointState, contract.JOINT_STATES,
                                    qos_for(contract.JOINT_STATES))
    traj = probe.create_publisher(JointTrajectory, "arm_controller/joint_trajectory", 10)
    wait_for(lambda: states.get_subscription_count() and traj.get_subscription_count()
             and diags, 30.0, what=lambda: f"arm_controller up\n{ctl.output()}")

    def send(q, age):
        msg = JointState(name=NAMES, position=[float(x) for x in q])
        msg.header.stamp = (probe.get_clock().now() - Duration(seconds=age)).to_msg()
        states.publish(msg)

    send(np.full(9, 0.1), 0.0)                 # fresh
    send(np.full(9, 0.9), 2.0)                 # 2 s late
    send(np.full(9, 0.5), 0.05)                # older than the newest used
    wait_for(lambda: {kv.key: kv.value for kv in diags[-1].values}.get("bad_joint_states")
             == "2", 10.0, what=lambda: f"two rejections\n{ctl.output()}")
    for _ in range(3):                         # keep the state fresh while it runs
        send(np.full(9, 0.1), 0.0)
    pub_goal = np.full(9, 0.1)
    pub_goal[0] = 0.2
    traj.publish(_trajectory(NAMES, [(1.0, pub_goal)]))
    wait_for(lambda: commands, 10.0, what="a command")
    assert np.allclose(commands[0], 0.1, atol=0.01), commands[0]   # from 0.1, not 0.9/0.5


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_goal_running_at_shutdown_is_aborted_saying_so(launch, rclpy_context, executor,
                                                         wait_for, sig):
    """SIGINT/SIGTERM to arm_controller while an action goal runs: the client gets the
    result (aborted, "arm_controller shutting down"), the process exits 0, the arm holds."""
    import rclpy
    from sensor_msgs.msg import JointState

    from hyperarm_control.client import TrajectoryClient, goal_from_points
    from hyperarm_description import contract
    from hyperarm_description.qos import observer_qos, qos_for

    launch("hyperarm_driver", "mock_driver")
    ctl = launch("hyperarm_control", "arm_controller")
    probe = rclpy.create_node("arm_controller_probe3", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    states: dict[str, float] = {}
    commands: list = []
    probe.create_subscription(JointState, contract.JOINT_STATES,
                              lambda m: states.update(zip(m.name, m.position)),
                              qos_for(contract.JOINT_STATES))
    probe.create_subscription(JointState, contract.JOINT_COMMAND, commands.append,
                              observer_qos(contract.JOINT_COMMAND))
    client = TrajectoryClient(probe)
    executor.add_node(probe)
    wait_for(lambda: client.server_ready() and all(n in states for n in NAMES), 60.0,
             what=lambda: f"arm_controller up\n{ctl.output()}")
    q0 = np.array([states[n] for n in NAMES])
    client.send(goal_from_points(NAMES, [4.0], [q0 + 0.4]))
    wait_for(lambda: client.accepted() and len(commands) > 30, 10.0, what="the goal running")
    ctl.proc.send_signal(sig)
    wait_for(client.done, 5.0, what="the result after the signal")
    status, result = client.result()
    assert status == 6 and "arm_controller shutting down" in result.error_string, \
        (status, result)
    assert ctl.proc.wait(timeout=10.0) == 0, ctl.output()[-2000:]
    held = np.array([states[n] for n in NAMES])
    time.sleep(0.5)
    assert np.abs(np.array([states[n] for n in NAMES]) - held).max() < 0.01
