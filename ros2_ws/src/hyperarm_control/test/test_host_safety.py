"""Core: host compensation's safety invariants (issue 24 items 1 and 5), no rclpy.

- Item 1: no command ever steps a joint further in one cycle than its velocity limit times
  the period, whatever the goal, the host motion or the singularity (property test over
  random postures, goals, host motions and periods), and the issue's scenario on the mock's
  simulated servos: tool0 0.62 m ahead, the rail streamed 0.2 m away at 0.1 m/s and back
  (the old core sent 1.5 rad in one cycle there, 2.6-3.65 rad in the issue's real-time runs).
- Item 5: the joints keep off their limits in the null space, and the status is judged from
  the measured tool (FK of the measured joints), not from the command.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hs

from hyperarm_control.benchmark.host_sim import DT, rail_reach, rail_sweep
from hyperarm_control.host import CompensationConfig, Compensator, HostState
from hyperarm_control.host.redundancy import ReactionMinimizer, RedundancyConfig
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.core

_KIN = Kinematics(variant="arm")
_VMAX = np.array([j.velocity for j in _KIN.desc.joints])


def _host_motion(rng: np.random.Generator, speed: float, jump: bool):
    """A host moving at a constant random twist (``speed`` m/s, up to ``speed`` rad/s per
    axis) from a random tilted pose, as :class:`HostState` at t s; with ``jump`` its pose
    jumps 5 cm and 0.1 rad at t = 0.3 s (a host pose source that glitches)."""
    lin = rng.normal(0.0, 1.0, 3)
    lin *= speed / np.linalg.norm(lin)
    ang = rng.uniform(-speed, speed, 3)
    p0 = np.eye(4)
    p0[:3, :3] = pin.exp3(rng.normal(0.0, 0.3, 3))
    kick = np.eye(4)
    kick[:3, :3] = pin.exp3(rng.normal(0.0, 0.1, 3))
    kick[:3, 3] = rng.normal(0.0, 0.05 / math.sqrt(3.0), 3)

    def at(t: float) -> HostState:
        pose = p0.copy()
        pose[:3, 3] += lin * t
        pose[:3, :3] = pin.exp3(ang * t) @ p0[:3, :3]
        if jump and t >= 0.3:
            pose = kick @ pose
        return HostState(pose, lin, ang)
    return at


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=hs.integers(0, 2**32 - 1), speed=hs.sampled_from([0.05, 0.1, 0.2, 0.4]),
       offset=hs.sampled_from([0.0, 0.01, 0.3]), dt=hs.sampled_from([0.005, 0.01, 0.02]),
       jump=hs.booleans(), near_stretch=hs.booleans())
def test_no_command_steps_a_joint_further_than_velocity_limit_times_period(
        seed, speed, offset, dt, jump, near_stretch):
    """Random postures (some near the stretched singularity), goals (some out of reach),
    host motions (constant twists that carry the goal out of reach and back, some with a
    jump) and periods: every command stays within one cycle's reach of the previous one and
    inside the margins. The old core broke it in most such runs (up to 3.65 rad, the
    issue's figure: the profile lead of an exploding feed-forward, added after the step
    limit)."""
    rng = np.random.default_rng(seed)
    comp = Compensator(_KIN)
    q0 = rng.uniform(0.1, 0.4, 9) * rng.choice([-1, 1], 9) if near_stretch \
        else _KIN.random_configuration(rng)
    host = _host_motion(rng, speed, jump)
    comp.start(q0, host(0.0))
    goal = comp.goal.copy()
    goal[:3, 3] += rng.normal(0.0, offset, 3)
    comp.set_goal(goal)
    prev = comp.sent.copy()
    for k in range(50):
        cmd = comp.step(host(k * dt), rng.uniform(0.0, 0.2), dt).command
        assert np.all(np.abs(cmd - prev) <= _VMAX * dt * (1 + 1e-9) + 1e-12), \
            (k, np.abs(cmd - prev).max(), _VMAX[0] * dt)
        assert np.all(cmd >= comp.lower - 1e-12) and np.all(cmd <= comp.upper + 1e-12)
        prev = cmd


def test_the_issue_scenario_rail_streamed_away_and_back_sends_no_jump():
    """Issue 24 item 1 on the simulated servos: tool0 0.62 m ahead, the rail 0.2 m away at
    0.1 m/s and back; the arm reaches full stretch and leaves it. The old core sent
    1.54 rad in one cycle here (and 104 reversals of more than 5 mrad: chatter)."""
    run = rail_reach()
    cmd = run["command"]
    steps = np.abs(np.diff(cmd, axis=0))
    worst = float(steps.max())
    d1 = np.diff(cmd, axis=0)
    chatter = int(((np.sign(d1[1:]) * np.sign(d1[:-1]) < 0) & (np.abs(d1[1:]) > 0.005)
                   & (np.abs(d1[:-1]) > 0.005)).sum())
    summary = (f"largest step {worst:.4f} rad, reversals > 5 mrad: {chatter}, statuses "
               f"{sorted(set(run['status']))}, rail {run['rail'].min():.3f} m")
    print(summary)
    assert run["rail"].min() < -0.19, summary               # the whole scenario ran
    assert "unreachable" in set(run["status"]), summary     # full stretch was reached
    assert np.all(steps <= _VMAX * DT * (1 + 1e-9)), summary
    assert chatter <= 20, summary
    # back at the start, the tool is where it was held
    assert run["position_error"][-1] < 1e-3, summary


def test_singularity_robust_damping_bounds_the_least_squares_gain():
    """At the stretched singularity (all joints 0) the damped least squares' answer to a
    unit error stays within 1 / (2 sqrt(singular_damping)) rad per m (with 1e-6 alone it
    was 500 times that)."""
    comp = Compensator(_KIN)
    _p, _r, j = _KIN.pose_jacobian_view(np.zeros(9))
    cfg = comp.config
    bound = 1.0 / (2.0 * math.sqrt(cfg.singular_damping))
    rng = np.random.default_rng(3)
    for _ in range(20):
        e = rng.normal(size=6)
        e /= np.linalg.norm(e)
        dq = comp._dls(j, e * 0.01, cfg.damping + comp.singular_damping(j))
        assert np.linalg.norm(dq) / 0.01 <= bound * 1.01, np.linalg.norm(dq) / 0.01
    assert comp.singular_damping(j) == pytest.approx(cfg.singular_damping)


def _postures_ahead_40(n: int) -> list[np.ndarray]:
    """IK postures with tool0 0.40 m ahead, 0.1 m up and 10 deg below forward (issue 24
    item 5), from seeded random starts."""
    rm = ReactionMinimizer(_KIN, RedundancyConfig(null_steps=0, max_iterations=300))
    target = _KIN.forward(np.zeros(9))
    target[:3, :3] = pin.rpy.rpyToMatrix(0.0, math.radians(10.0), 0.0) @ target[:3, :3]
    target[:3, 3] = (0.40, 0.0, 0.1)
    out = []
    for seed in range(40):
        try:
            out.append(rm.solve(target, np.random.default_rng(seed).uniform(-2, 2, 9)))
        except Exception:   # noqa: BLE001 - a seed the IK does not converge from
            continue
        if len(out) == n:
            break
    return out


@pytest.mark.slow
def test_joints_keep_off_their_limits_and_the_status_follows_the_measured_tool():
    """Issue 24 item 5: the rail sweep (+-0.2 m at 0.2 m/s) from 3 IK postures with tool0
    0.40 m ahead, 10 deg below forward. The old core drove a joint to its limit margin in
    each (the tool then jumped to 17-29 mm off) while its status stayed ``tracking``: now
    every joint stays more than 0.05 rad off its margin, and wherever the measured tool is
    beyond the tracking tolerance for 3 states in a row the status says ``off_track``."""
    cfg = CompensationConfig()
    margin_lo, margin_hi = _KIN.lower + cfg.limit_margin, _KIN.upper - cfg.limit_margin
    postures = _postures_ahead_40(3)
    assert len(postures) == 3
    for q0 in postures:
        run = rail_sweep(q0=q0)
        cmd = run["command"]
        room = float(np.minimum(cmd - margin_lo, margin_hi - cmd).min())
        p, o = run["position_error"], run["orientation_error"]
        beyond = (p > cfg.track_position_tolerance) | (o > cfg.track_orientation_tolerance)
        status = np.asarray(run["status"])
        run3 = beyond & np.roll(beyond, 1) & np.roll(beyond, 2)
        run3[:2] = False
        summary = (f"q0 {np.round(q0, 2).tolist()}: room to the margins {room:.3f} rad, "
                   f"max error {p.max() * 1e3:.1f} mm, {math.degrees(o.max()):.2f} deg, "
                   f"{int(run3.sum())} states beyond for 3 in a row, statuses "
                   f"{sorted(set(status))}")
        print(summary)
        assert room > 0.05, summary
        # the loop judges the state it is given (the error here is of the same state)
        assert np.all(np.isin(status[run3], ["off_track", "unreachable"])), summary
        assert float(run["answered"]) == 1.0
