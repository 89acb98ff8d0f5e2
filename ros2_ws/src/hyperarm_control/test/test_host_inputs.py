"""host_compensation's inputs (issue 24 items 3 and 5): late, out-of-order and malformed
host_pose and joint_states are rejected whole, counted and logged per kind naming the field;
base_reaction differentiates the joint velocities at the states' stamps.

Core tests of ``hyperarm_control.host.inputs``; node tests drive the real node's callbacks
in-process, one message at a time (deterministic; the publishers are the node's own,
recorded), on the fixed arm with host_pose as the host.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from hyperarm_description import contract
from hyperarm_control.host import ReactionModel
from hyperarm_control.host.inputs import JOINT_STATE_REASONS, POSE_REASONS, joint_state_problem, \
    pose_problem
from hyperarm_ik.kinematics import Kinematics

ARM = list(contract.ARM_JOINTS)
Q0 = np.array([1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726])


# -- core -----------------------------------------------------------------------------------
@pytest.mark.core
@pytest.mark.parametrize("frame, pos, quat, reason, field", [
    ("map", (0, 0, 0), (0, 0, 0, 1), "frame", "frame_id"),
    ("world", (0, math.nan, 0), (0, 0, 0, 1), "position_nan", "pose.position.y"),
    ("world", (0, 0, math.inf), (0, 0, 0, 1), "position_inf", "pose.position.z"),
    ("world", (0, 0, 0), (math.nan, 0, 0, 1), "orientation_nan", "pose.orientation.x"),
    ("world", (0, 0, 0), (0, 0, -math.inf, 1), "orientation_inf", "pose.orientation.z"),
    ("world", (0, 0, 0), (0, 0, 0, 0.5), "quaternion_norm", "unit quaternion"),
])
def test_each_malformed_pose_kind_has_its_reason_and_names_the_field(frame, pos, quat,
                                                                      reason, field):
    got = pose_problem(frame, pos, quat, "world", "host_pose ignored")
    assert got is not None and got[0] == reason and field in got[1], got
    assert reason in POSE_REASONS
    assert pose_problem("world", (0.1, 0, 0), (0, 0, 0, 1), "world", "x") is None


@pytest.mark.core
@pytest.mark.parametrize("names, pos, vel, reason, field", [
    (["a", "b"], [0.0], [], "length", "position has 1 values"),
    (["a", "a"], [0.0, 0.0], [], "duplicate", "'a'"),
    (["a", "b"], [0.0, math.nan], [], "position_nan", "position of b"),
    (["a", "b"], [math.inf, 0.0], [], "position_inf", "position of a"),
    (["a", "b"], [0.0, 0.0], [math.nan, 0.0], "velocity_nan", "velocity of a"),
])
def test_each_malformed_joint_state_kind_has_its_reason_and_names_the_joint(names, pos, vel,
                                                                             reason, field):
    got = joint_state_problem(names, pos, vel, [], needed_velocity={"a"})
    assert got is not None and got[0] == reason and field in got[1], got
    assert reason in JOINT_STATE_REASONS
    # the velocity of a joint the reaction does not use may be anything
    assert joint_state_problem(["a", "b"], [0.0, 0.0], [0.0, math.nan], [], {"a"}) is None


# -- node -----------------------------------------------------------------------------------
class Harness:
    """The node, not spun: its callbacks called directly; its joint_command, base_reaction
    and warnings recorded."""

    def __init__(self, context, **params) -> None:
        from rclpy.parameter import Parameter

        from hyperarm_control.host_compensation_node import HostCompensationNode

        self.node = HostCompensationNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in {"stale_timeout": 5.0, **params}.items()])
        self.commands: list[np.ndarray] = []
        self.reactions: list[np.ndarray] = []
        self.shown: list[str] = []          # warnings that passed the throttle
        self.node._cmd.publish = lambda m: self.commands.append(np.array(m.position))

        def reaction(m):
            f, t = m.wrench.force, m.wrench.torque
            self.reactions.append(np.array([f.x, f.y, f.z, t.x, t.y, t.z]))
        self.node._wrench.publish = reaction
        message = self.node._throttle.message

        def record(text, reason=None):
            out = message(text, reason)
            if out is not None:
                self.shown.append(out)
            return out
        self.node._throttle.message = record

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def state(self, q=Q0, stamp: float | None = None, dq=None, names=ARM) -> None:
        msg = JointState()
        t = self.now() if stamp is None else stamp
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t % 1.0) * 1e9))
        msg.name = list(names)
        msg.position = [float(v) for v in q]
        if dq is not None:
            msg.velocity = [float(v) for v in dq]
        self.node._on_joint_states(msg)

    def host(self, x: float = 0.0, stamp: float | None = None, quat=(0.0, 0.0, 0.0, 1.0),
             y: float = 0.0) -> None:
        msg = PoseStamped()
        msg.header.frame_id = contract.WORLD_FRAME
        t = self.now() if stamp is None else stamp
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t % 1.0) * 1e9))
        msg.pose.position.x, msg.pose.position.y = x, y
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = quat
        self.node._on_host_pose(msg)

    def enable(self) -> None:
        res = self.node._on_enable(SetBool.Request(data=True), SetBool.Response())
        assert res.success, res.message

    def diagnostics(self) -> dict:
        from hyperarm_control.host_compensation_node import HostCompensationNode  # noqa: F401
        out = {}
        self.node._diag.publish = lambda arr: out.update(
            {kv.key: kv.value for kv in arr.status[0].values})
        self.node._publish_diagnostics()
        return out


@pytest.mark.node
def test_a_late_or_out_of_order_host_pose_is_rejected_counted_and_said(rclpy_context):
    """Issue 24 item 3: compensation running on a 100 Hz host_pose stream; one pose stamped
    now - 2 s and 3 cm off, then one 30 ms older than the newest, also 3 cm off. Before,
    each was taken as the current host pose (the tracker let an older pose replace the
    newer ones) and the command moved the tool about 7 mm; now the command does not move,
    both are counted (stale, out_of_order) and logged with their reason."""
    h = Harness(rclpy_context)
    for _ in range(5):
        h.host()
        h.state()
    h.enable()
    for _ in range(20):                       # the steady stream: 100 Hz of poses at rest
        h.host()
        h.state()
    steady = h.commands[-1].copy()
    t = h.now()
    h.host(x=0.03, stamp=t - 2.0)              # late by 2 s, 3 cm off
    h.state()
    h.host(x=0.03, stamp=t - 0.03)             # out of order (older than the newest used)
    h.state()
    h.state()
    kin = Kinematics(variant="arm")
    moved = max(float(np.linalg.norm(kin.forward(c)[:3, 3] - kin.forward(steady)[:3, 3]))
                for c in h.commands[-3:])
    d = h.diagnostics()
    assert moved < 1e-4, f"the command moved the tool {moved * 1e3:.2f} mm"
    assert d["host_pose_rejected_stale"] == "1" and d["host_pose_rejected_out_of_order"] == "1"
    assert any("stamped 2.0" in s and "max_age" in s for s in h.shown), h.shown
    assert any("before the newest one used" in s for s in h.shown), h.shown
    h.node.destroy_node()


@pytest.mark.node
def test_three_malformed_host_pose_kinds_in_a_row_are_three_messages(rclpy_context):
    """Issue 24 item 3: NaN, inf and a bad quaternion in a row were one throttled message
    (one text for all); each kind now has its reason and names the field."""
    h = Harness(rclpy_context)
    h.host(x=math.nan)
    h.host(y=math.inf)
    h.host(quat=(0.0, 0.0, 0.0, 0.5))
    h.host(quat=(math.nan, 0.0, 0.0, 1.0))
    assert len(h.shown) == 4, h.shown
    for field, s in zip(("pose.position.x", "pose.position.y", "unit quaternion",
                         "pose.orientation.x"), h.shown):
        assert field in s, (field, s)
    d = h.diagnostics()
    assert d["host_pose_rejected_position_nan"] == "1" and d["host_pose_rejected_quaternion_norm"] == "1"
    assert h.node._tracker.state is None                  # none was used
    h.node.destroy_node()


@pytest.mark.node
def test_joint_states_late_out_of_order_or_malformed_get_no_command(rclpy_context):
    """A joint state with a NaN, an older stamp than the newest used, or stamped 2 s ago is
    rejected whole: no command answers it (before, the out-of-order and late ones were
    answered from their old joints and the NaN one entered the cache)."""
    h = Harness(rclpy_context)
    for _ in range(3):
        h.host()
        h.state()
    h.enable()
    h.host()
    h.state()
    n = len(h.commands)
    t = h.now()
    bad = Q0.copy()
    bad[2] = math.nan
    h.state(q=bad)
    h.state(stamp=t - 0.05)                  # older than the newest used
    h.state(stamp=t - 2.0)                   # stale
    assert len(h.commands) == n, "a rejected joint state was answered"
    assert math.isfinite(h.node._cache.position["joint3"])
    h.state()
    assert len(h.commands) == n + 1
    d = h.diagnostics()
    assert d["joint_states_rejected_position_nan"] == "1"
    assert d["joint_states_rejected_out_of_order"] == "1" and d["joint_states_rejected_stale"] == "1"
    assert any("position of joint3 is NaN" in s for s in h.shown), h.shown
    h.node.destroy_node()


@pytest.mark.node
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_base_reaction_differentiates_at_the_states_stamps(rclpy_context, seed):
    """Issue 24 item 5: joint velocities ramping at a constant acceleration, stamped 10 ms
    apart but arriving in bursts (several at once, as a loaded executor delivers them):
    every reaction equals RNEA with that acceleration. Differenced at arrival (before),
    a burst's near-equal arrival times made the acceleration, and the moment, spike."""
    rng = np.random.default_rng(seed)
    h = Harness(rclpy_context, reaction_host_acceleration="zero")
    kin = Kinematics(variant="arm")
    model = ReactionModel(kin)
    ddq = rng.uniform(-2.0, 2.0, 9)
    q0 = kin.random_configuration(rng)
    t0 = h.now() - 0.3
    expected = []
    for k in range(25):
        t = 0.01 * k
        dq = ddq * t
        q = q0 + 0.5 * ddq * t * t
        h.state(q=q, dq=dq, stamp=t0 + t)
        expected.append(model.wrench(q, dq, ddq))
    got = np.array(h.reactions[1:])              # the first has no acceleration yet
    err = np.abs(got - np.array(expected[1:]))
    assert len(got) == 24
    # 1e-4 N, N·m: epoch stamps as float seconds resolve ~0.2 us, 2e-5 of a 10 ms period
    # (the error was 0.29 N·m RMS; differenced at arrival a burst gives far more)
    assert err.max() < 1e-4, err.max()
    h.node.destroy_node()
