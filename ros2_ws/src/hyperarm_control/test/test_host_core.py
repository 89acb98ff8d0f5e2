"""Core tier of host-motion compensation and the mount reaction (no rclpy).

Compensation: on a simulated moving host (rail motion, a 6-D sway) the command keeps
host_pose(t) * FK(q) at the world goal; no cycle moves a joint more than its step limit;
an unreachable goal is said so and the command holds still at the closest configuration
(never a jump), then tracking resumes. Reaction: at rest it is the links' weight with the
moment c x m g (pinocchio's total mass and CoM), a contact wrench and a base acceleration
enter as statics say, and it matches the rail_arm model's own RNEA at the carriage joint.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.model import load_description
from hyperarm_ik.errors import IKError
from hyperarm_control.host import (CompensationConfig, Compensator, HostConfigError, HostGoalError,
                              HostState, HostStateError, NotStartedError, RailHost,
                              ReactionModel, Status)
from hyperarm_ik.kinematics import Kinematics, rotation_angle

pytestmark = pytest.mark.core

# tool0 pointing down 0.2 m in front of the base: the wrist point stays well inside its
# reach while the base moves +-0.2 m (the fixed-orientation workspace is small)
Q0 = np.array([1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726])
DT = 0.01


@pytest.fixture(scope="module")
def kin():
    return Kinematics(variant="arm")


@pytest.fixture(scope="module")
def rail():
    return RailHost(load_description(variant="rail_arm"))


def _tool_error(comp, host_pose, q):
    t = host_pose @ comp.kin.forward(q)
    return (float(np.linalg.norm(t[:3, 3] - comp.goal[:3, 3])),
            rotation_angle(comp.goal[:3, :3], t[:3, :3]))


def test_rail_motion_keeps_the_tool_in_the_world_with_feed_forward(kin, rail):
    """The rail moves +-0.2 m at up to 0.2 m/s (0.2 sin t); the command is computed for
    the predicted host pose one latency ahead, judged against the host pose when it takes
    effect."""
    comp = Compensator(kin)
    goal = comp.start(Q0, rail.state(0.0))
    latency = 0.03
    worst_p = worst_o = 0.0
    limited = 0
    for i in range(629):                      # one period, 2 pi s
        t = i * DT
        x, v = 0.2 * math.sin(t), 0.2 * math.cos(t)
        step = comp.step(rail.state(x, v), latency, DT)
        assert step.status is not Status.UNREACHABLE, step.reason
        limited += step.step_limited
        x_later = 0.2 * math.sin(t + latency)
        e_p, e_o = _tool_error(comp, rail.pose(x_later), step.q)
        worst_p, worst_o = max(worst_p, e_p), max(worst_o, e_o)
    assert np.allclose(comp.goal, goal)
    assert worst_p < 0.5e-3 and worst_o < math.radians(0.1), (worst_p, worst_o)
    assert limited == 0


def test_without_feed_forward_the_same_motion_lags(kin, rail):
    """The prediction is what keeps the error down (the test above can fail): with a zero
    horizon, the pose at the time the command takes effect is v * latency off."""
    comp = Compensator(kin)
    comp.start(Q0, rail.state(0.0))
    errs = []
    for i in range(50):
        x = 0.2 * i * DT
        step = comp.step(rail.state(x, 0.2), 0.0, DT)
        errs.append(_tool_error(comp, rail.pose(x + 0.2 * 0.03), step.q)[0])
    assert max(errs) > 5e-3


def test_six_d_sway_is_compensated(kin):
    comp = Compensator(kin)
    base = np.eye(4)
    comp.start(Q0, HostState(base))
    worst = 0.0
    for i in range(200):
        t = i * DT
        w = 2 * math.pi * 0.5
        pose = np.eye(4)
        pose[:3, 3] = (0.02 * math.sin(w * t), 0.0, 0.01 * math.sin(w * t))
        angle = math.radians(5.0) * math.sin(w * t)
        pose[:3, :3] = pin.exp3(np.array([angle, 0.0, 0.0]))
        lin = np.array([0.02 * w * math.cos(w * t), 0.0, 0.01 * w * math.cos(w * t)])
        ang = np.array([math.radians(5.0) * w * math.cos(w * t), 0.0, 0.0])
        step = comp.step(HostState(pose, lin, ang), 0.0, DT)
        assert step.status is Status.TRACKING, (i, step)
        worst = max(worst, _tool_error(comp, pose, step.q)[0])
    assert worst < 1e-4


def test_every_cycle_respects_the_step_limit_and_the_joint_limits(kin, rail):
    """A goal 0.1 m away is approached at the step limit, converging, then tracked."""
    cfg = CompensationConfig()
    comp = Compensator(kin, cfg)
    comp.start(Q0, rail.state(0.0))
    goal = comp.goal.copy()
    goal[:3, 3] += (-0.06, 0.08, 0.0)
    comp.set_goal(goal)
    max_step = np.array([j.velocity for j in kin.desc.joints]) * cfg.speed_scale * DT
    prev = comp.q.copy()
    statuses = []
    for _ in range(300):
        step = comp.step(rail.state(0.0), 0.0, DT)
        assert np.all(np.abs(step.q - prev) <= max_step * (1 + 1e-9)), step.q - prev
        assert np.all(step.q >= kin.lower + cfg.limit_margin - 1e-12)
        assert np.all(step.q <= kin.upper - cfg.limit_margin + 1e-12)
        statuses.append(step.status)
        prev = step.q
    assert Status.CONVERGING in statuses[:3]
    assert statuses[-1] is Status.TRACKING
    assert _tool_error(comp, rail.pose(0.0), prev)[0] < 1e-3


def test_unreachable_is_said_and_held_without_a_jump_then_tracking_resumes(kin, rail):
    comp = Compensator(kin)
    comp.start(Q0, rail.state(0.0))
    good = comp.goal.copy()
    far = good.copy()
    far[:3, 3] = (1.6, 0.0, 0.2)                   # beyond the arm's reach (~0.7 m)
    comp.set_goal(far)
    qs = []
    for _ in range(300):
        step = comp.step(rail.state(0.0), 0.0, DT)
        qs.append(step.q)
    assert step.status is Status.UNREACHABLE
    assert "unreachable" in step.reason and "holding" in step.reason
    assert np.abs(qs[-1] - qs[-2]).max() < 1e-6       # it holds still, it does not wander
    assert np.all(np.abs(np.diff(qs, axis=0)) <= 3.0 * 0.8 * DT + 1e-9)
    tool = rail.pose(0.0) @ kin.forward(qs[-1])
    assert tool[0, 3] > good[0, 3] + 0.05               # stretched towards the far goal
    comp.set_goal(good)
    for _ in range(300):
        step = comp.step(rail.state(0.0), 0.0, DT)
    assert step.status is Status.TRACKING and step.reason == ""


def test_bad_inputs_are_precise_errors(kin, rail):
    comp = Compensator(kin)
    with pytest.raises(NotStartedError):
        comp.step(rail.state(0.0), 0.0, DT)
    with pytest.raises(NotStartedError):
        comp.set_goal(np.eye(4))
    comp.start(Q0, rail.state(0.0))
    with pytest.raises(HostGoalError):
        comp.set_goal(np.full((4, 4), np.nan))
    with pytest.raises(HostGoalError):
        comp.set_goal(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(HostStateError):
        comp.step(rail.state(0.0), 0.0, 0.0)
    with pytest.raises(HostStateError):
        HostState(np.eye(4), [0.0, math.inf, 0.0])
    with pytest.raises(HostStateError):
        rail.state(math.nan)
    with pytest.raises(IKError):
        comp.start(Q0[:5], rail.state(0.0))
    for bad in ({"iterations": 0}, {"speed_scale": 2.0}, {"damping": -1.0},
                {"max_horizon": math.nan}, {"iterations": True}):
        with pytest.raises(HostConfigError):
            CompensationConfig(**bad)
    with pytest.raises(HostConfigError):
        Compensator(Kinematics(variant="rail_arm"))
    with pytest.raises(HostConfigError):
        RailHost(load_description(variant="arm"))


# --- reaction ------------------------------------------------------------------------------
G = np.array([0.0, 0.0, -9.81])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reaction_at_rest_is_the_weight_and_its_moment(kin, seed):
    model = ReactionModel(kin)
    q = np.random.default_rng(seed).uniform(kin.lower, kin.upper) * 0.5
    w = model.wrench(q)
    m, c = model.mass_and_com(q)
    assert m > 1.0
    np.testing.assert_allclose(w[:3], m * G, atol=1e-9)
    np.testing.assert_allclose(w[3:], np.cross(c, m * G), atol=1e-9)


def test_reaction_with_a_contact_and_a_base_acceleration(kin):
    model = ReactionModel(kin)
    q = Q0
    m, c = model.mass_and_com(q)
    p_tool = kin.forward(q)[:3, 3]
    f = np.array([1.0, -2.0, -5.0])            # the tool pushes the environment with f ...
    tau = np.array([0.1, 0.0, -0.2])           # ... and a torque
    w = model.wrench(q, contact_wrench_base=np.concatenate((f, tau)))
    # statics of the arm: mount + gravity - contact = 0; the arm gives the mount the rest
    np.testing.assert_allclose(w[:3], m * G - f, atol=1e-9)
    np.testing.assert_allclose(w[3:], np.cross(c, m * G) - np.cross(p_tool, f) - tau,
                               atol=1e-9)
    a = np.array([0.5, 0.0, 0.0])              # the carriage accelerates along x
    w = model.wrench(q, base_acceleration=a)
    np.testing.assert_allclose(w[:3], m * (G - a), atol=1e-9)


def test_reaction_in_motion_matches_the_rail_models_rnea(kin):
    """Moving arm on an accelerating carriage: the force along the rail at the rail joint
    of the rail_arm model (arm + carriage) minus the carriage's own m a is the arm's
    reaction along the rail."""
    desc = load_description(variant="rail_arm")
    rk = Kinematics(desc)
    model = ReactionModel(kin)
    rng = np.random.default_rng(7)
    q, dq, ddq = (rng.uniform(-0.5, 0.5, 9) for _ in range(3))
    a_rail = 0.8
    tau = pin.rnea(rk.model, rk.model.createData(), np.r_[0.0, q], np.r_[0.0, dq],
                   np.r_[a_rail, ddq])
    w = model.wrench(q, dq, ddq, base_acceleration=[a_rail, 0.0, 0.0])
    carriage = desc.rail.carriage_mass
    assert tau[0] == pytest.approx(carriage * a_rail - w[0], abs=1e-9)
    assert abs(w[0]) > 0.1


def test_reaction_rejects_malformed_states(kin):
    model = ReactionModel(kin)
    with pytest.raises(HostStateError):
        model.wrench(Q0[:3])
    with pytest.raises(HostStateError):
        model.wrench(Q0, dq=np.full(9, np.nan))
    with pytest.raises(HostConfigError):
        ReactionModel(Kinematics(variant="rail_arm"))


def test_delay_estimator_finds_a_known_delay_and_ignores_standstill():
    from hyperarm_control.host import DelayEstimator

    est = DelayEstimator(0.01, gain=0.2)
    delay = 0.045
    for i in range(200):                       # commands ramp at 0.5 rad/s, every 10 ms
        t = i * DT
        est.commanded(t, np.full(9, 0.5 * t))
        est.measured(t, np.full(9, 0.5 * max(t - delay, 0.0)))
    assert est.delay == pytest.approx(delay, abs=DT / 2 + 1e-9)
    still = DelayEstimator(0.02)
    for i in range(100):
        still.commanded(i * DT, np.zeros(9))
        still.measured(i * DT, np.zeros(9))
    assert still.delay == 0.02 and still.samples == 0
    with pytest.raises(HostConfigError):
        DelayEstimator(-1.0)


def _enabled_loop(kin):
    from hyperarm_control.host import CompensationConfig, DelayEstimator
    from hyperarm_control.host.loop import CompensationLoop
    loop = CompensationLoop(Compensator(kin, CompensationConfig()), DelayEstimator(0.04), 0.1,
                            host_from_states=False)
    host = HostState(np.eye(4))
    loop.on_state(0.0, 0.0, Q0, host, 0.0, 0.0)
    ok, message, _ = loop.enable(0.0, Q0, host, "host_pose")
    assert ok, message
    return loop, host


def test_loop_stops_on_silence_but_not_on_its_own_scheduling_gap(kin):
    """Joint states stopping stop the compensation (latched); a gap in the loop's own
    calls longer than stale_timeout (the node not run: a loaded machine) is not taken for
    the inputs' silence: neither the joint states' (check_stale) nor, for stale_timeout
    after it, the host pose's (queued states are read before the queued host pose: the
    clean-clone run's sway failure, the node stopped mid-sway)."""
    loop, host = _enabled_loop(kin)
    for t in np.arange(0.01, 0.095, 0.01):
        assert loop.check_stale(float(t)) == []
    assert loop.check_stale(0.105) and not loop.enabled
    # starved 0.3 s: the check right after is not judged, the queued state runs a cycle
    # with the host pose received before the gap
    loop, host = _enabled_loop(kin)
    assert loop.check_stale(0.05) == []
    assert loop.check_stale(0.35) == [] and loop.enabled
    for k in range(3):       # a burst of queued states before the queued host pose
        command, log = loop.on_state(0.351 + 0.001 * k, 0.35, Q0, host, 0.0, 0.0)
        assert command is not None and loop.enabled, log
    assert loop.check_stale(0.36) == [] and loop.enabled
    # the host pose then stays silent: judged stale_timeout after the gap
    command, log = loop.on_state(0.44, 0.44, Q0, host, 0.0, 0.0)
    assert loop.enabled, log
    command, log = loop.on_state(0.46, 0.46, Q0, host, 0.0, 0.0)
    assert command is None and not loop.enabled and "host pose stale" in loop.reason
    # a host pose silent while the loop runs (states every 10 ms): stopped
    loop, host = _enabled_loop(kin)
    for t in np.arange(0.01, 0.2, 0.01):
        command, log = loop.on_state(float(t), float(t), Q0, host, 0.0, 0.0)
        if not loop.enabled:
            break
    assert not loop.enabled and 0.1 < t < 0.12
    assert "host pose stale" in loop.reason


def test_latest_contact_wrench_is_used_while_fresh_and_refuses_bad_values():
    """LatestWrench: the newest wrench while at most ``timeout`` s old, then None; a
    malformed one raises HostStateError and the last good one stays; timeout 0 = never."""
    from hyperarm_control.host import HostStateError, LatestWrench

    latest = LatestWrench(0.2)
    assert latest.get(0.0) is None
    latest.update(1.0, [0.0, 0.0, -2.0, 0.0, 0.1, 0.0])
    np.testing.assert_array_equal(latest.get(1.15), [0.0, 0.0, -2.0, 0.0, 0.1, 0.0])
    assert latest.get(1.25) is None
    with pytest.raises(HostStateError):
        latest.update(1.3, [0.0, math.nan, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(HostStateError):
        latest.update(1.3, [1.0, 2.0])
    assert latest.get(1.1) is not None and latest.get(1.1)[2] == -2.0
    never = LatestWrench(0.0)
    never.update(0.0, np.zeros(6))
    assert never.get(0.0) is None
    for bad in (-1.0, math.inf, True, "0.2"):
        with pytest.raises(HostConfigError):
            LatestWrench(bad)


def test_host_acceleration_is_differenced_over_its_baseline():
    """HostAccelerationEstimator: velocities of a constant acceleration at 10 ms stamps give
    that acceleration once a baseline (50 ms) is spanned, None before; a repeated stamp
    returns the last estimate; after reset it waits for a baseline again (a velocity jump
    right after a reset is no spike); bad settings and velocities are precise errors."""
    from hyperarm_control.host import HostAccelerationEstimator, HostStateError

    est = HostAccelerationEstimator(0.05)
    a = np.array([2.0, -1.0, 0.5])
    got = [est.update(0.01 * k, a * 0.01 * k) for k in range(12)]
    assert all(g is None for g in got[:5]) and got[5] is not None
    for g in got[5:]:
        np.testing.assert_allclose(g, a, rtol=1e-9)
    np.testing.assert_allclose(est.update(0.11, np.zeros(3)), a)     # same stamp: the last
    est.reset()
    assert est.update(0.2, np.array([5.0, 0.0, 0.0])) is None        # no spike after a reset
    assert est.update(0.21, np.array([5.0, 0.0, 0.0])) is None
    with pytest.raises(HostStateError):
        est.update(0.3, [math.nan, 0.0, 0.0])
    for bad in (0.0, 2.0, True, "0.05"):
        with pytest.raises(HostConfigError):
            HostAccelerationEstimator(bad)
