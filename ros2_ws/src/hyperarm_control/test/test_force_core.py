"""Core tier of the force controller (no rclpy): Jacobians and gravity against finite
differences, the law against an independent numerical reference, saturation properties,
goal validation, the wrench estimate and the calibration fit."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.model import load_description
from hyperarm_control.force import (CalibrationError, EstimatorConfig, ForceConfigError, HybridLaw, InvalidGoalError,
                               LawConfig, Payload, StateError, WrenchEstimator, fit_calibration,
                               load_calibration, make_goal, save_calibration, to_tool)
from hyperarm_control.force.calibration import TorqueCalibration
from hyperarm_control.force.law import (payload_jacobian, pose_error, rate_limit, scale_into_limits,
                                   scale_wrench)
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.core

RNG_SEED = 7


@pytest.fixture(scope="module")
def kin() -> Kinematics:
    return Kinematics(load_description())


@pytest.fixture(scope="module")
def rail_kin() -> Kinematics:
    return Kinematics(load_description(variant="rail_arm"))


def _configs(kin: Kinematics, n: int = 5) -> list[np.ndarray]:
    rng = np.random.default_rng(RNG_SEED)
    return [kin.random_configuration(rng) * 0.8 for _ in range(n)]


def _pose(kin: Kinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = kin.forward(q)
    return t[:3, 3], t[:3, :3]


def _fd_jacobian(kin: Kinematics, q: np.ndarray, com=(0.0, 0.0, 0.0), h: float = 1e-6):
    """6 x n Jacobian of the point ``com`` of tool0 by central differences: linear rows
    from positions, angular rows from log3(R(q+h) R(q-h)^T) / 2h."""
    out = np.zeros((6, kin.nq))
    for i in range(kin.nq):
        dq = np.zeros(kin.nq)
        dq[i] = h
        tp, tm = kin.forward(q + dq), kin.forward(q - dq)
        pp = tp[:3, 3] + tp[:3, :3] @ np.asarray(com)
        pm = tm[:3, 3] + tm[:3, :3] @ np.asarray(com)
        out[:3, i] = (pp - pm) / (2 * h)
        out[3:, i] = pin.log3(tp[:3, :3] @ tm[:3, :3].T) / (2 * h)
    return out


def _potential(kin: Kinematics, q: np.ndarray, payload: Payload) -> float:
    """Potential energy (J) of the links (pinocchio) and the payload (m g z)."""
    v = pin.computePotentialEnergy(kin.model, kin.model.createData(), q)
    t = kin.forward(q)
    z = (t[:3, 3] + t[:3, :3] @ np.asarray(payload.com))[2]
    return float(v + payload.mass * 9.81 * z)


def test_tool_jacobian_matches_finite_differences(kin, rail_kin):
    for k in (kin, rail_kin):
        for q in _configs(k, 4):
            np.testing.assert_allclose(k.jacobian(q), _fd_jacobian(k, q), atol=1e-6)


def test_payload_jacobian_matches_finite_differences(kin):
    com = (0.01, -0.03, 0.05)
    for q in _configs(kin, 4):
        t = kin.forward(q)
        j = payload_jacobian(kin.jacobian(q), t[:3, :3], com)
        np.testing.assert_allclose(j, _fd_jacobian(kin, q, com)[:3], atol=1e-6)


def test_gravity_is_the_gradient_of_the_potential_energy(kin):
    law = HybridLaw(kin)
    payload = Payload(0.2, (0.0, -0.02, 0.03))
    h = 1e-6
    for q in _configs(kin, 3):
        g = law.gravity.torques(q, payload)
        fd = np.array([(_potential(kin, q + h * e, payload) - _potential(kin, q - h * e, payload))
                       / (2 * h) for e in np.eye(kin.nq)])
        np.testing.assert_allclose(g, fd, atol=1e-5)
        # the payload's share is real: 0.2 kg changes the joint torques
        assert np.abs(g - law.gravity.torques(q, Payload())).max() > 0.01


def _reference_torque(kin, cfg: LawConfig, q, dq, p0, r0, k, s, fd, payload, dt=0.01):
    """The law written out independently: FK/Jacobian by finite differences, gravity by the
    gradient of the potential, the null-space projector by an SVD pseudo-inverse with the
    same damping, no saturation (the test keeps it inactive)."""
    p, r = _pose(kin, q)
    e = np.r_[p0 - p, pin.log3(r0 @ r.T)]
    j = _fd_jacobian(kin, q)
    f = k * e - np.asarray(cfg.damping) * (j @ dq) + np.where(s, fd, 0.0)
    h = 1e-6
    grav = np.array([(_potential(kin, q + h * ei, payload) - _potential(kin, q - h * ei, payload))
                     / (2 * h) for ei in np.eye(kin.nq)])
    u, sig, vt = np.linalg.svd(j, full_matrices=False)
    lam2 = cfg.singular_damping ** 2
    j_pinv = vt.T @ np.diag(sig / (sig ** 2 + lam2)) @ u.T
    null = np.eye(kin.nq) - j_pinv @ j
    lo, hi, m = kin.lower, kin.upper, cfg.limit_margin
    # the barrier k_l m (m - d) / max(d, m/4) within m of a limit, the posture spring
    # faded by the smallest distance to a limit (docs/force.md)
    push = np.zeros(kin.nq)
    for i in range(kin.nq):
        for d, sign in ((q[i] - lo[i], 1.0), (hi[i] - q[i], -1.0)):
            if d < m:
                push[i] += sign * cfg.limit_stiffness * m * (m - d) / max(d, m / 4)
    fade = min(1.0, min(np.min(q - lo), np.min(hi - q)) / m)
    # the spring's reference starts at the posture of reset (q) and moves posture_speed x dt
    # towards the posture (0) per cycle: the first cycle's
    ref = q + np.clip(0.0 - q, -cfg.posture_speed * dt, cfg.posture_speed * dt)
    tau0 = fade ** 2 * cfg.posture_stiffness * (ref - q) + push
    return grav + j.T @ f + null @ tau0 - cfg.joint_damping * dq


def test_law_matches_the_numerical_reference(kin):
    cfg = LawConfig(torque_rate=1e6, max_force=1e3, max_moment=100.0, torque_margin=1.0,
                    max_speed=2.0, max_angular_speed=10.0)
    law = HybridLaw(kin, cfg)
    payload = Payload(0.1, (0.0, 0.0, 0.02))
    law.payload = payload
    rng = np.random.default_rng(3)
    for q in _configs(kin, 3):
        dq = rng.normal(0.0, 0.2, kin.nq)
        p, r = _pose(kin, q)
        p0 = p + rng.normal(0.0, 0.004, 3)
        r0 = pin.exp3(rng.normal(0.0, 0.01, 3)) @ r
        k = np.array([300.0, 500.0, 800.0, 5.0, 8.0, 10.0])
        s = np.array([False, False, True, False, True, False])
        fd = np.array([0.0, 0.0, -2.0, 0.0, 0.1, 0.0])
        quat = pin.Quaternion(r0)
        goal = make_goal(kin, cfg, "base_link", p0, [quat.x, quat.y, quat.z, quat.w], k, s, fd)
        law.reset(q)
        law._ref_p, law._ref_r = p0.copy(), r0.copy()   # the reference at the goal already
        cmd = law.step(q, dq, goal, 0.01)
        assert cmd.wrench_scale == 1.0 and cmd.joint_scale == 1.0 and not cmd.rate_limited
        ref = _reference_torque(kin, cfg, q, dq, p0, r0, k, s, fd, payload)
        np.testing.assert_allclose(cmd.tau, ref, atol=2e-4)


def test_feed_forward_only_on_force_axes(kin):
    cfg = LawConfig(torque_rate=1e6)
    law = HybridLaw(kin, cfg)
    q = _configs(kin, 1)[0]
    p, r = _pose(kin, q)
    quat = pin.Quaternion(r)
    goal = make_goal(kin, cfg, "base_link", p, [quat.x, quat.y, quat.z, quat.w], [0.0] * 6,
                     [False, False, True, False, False, False], [5.0, 5.0, -3.0, 0, 0, 0])
    np.testing.assert_allclose(goal.wrench, [0, 0, -3.0, 0, 0, 0])
    law.reset(q)
    cmd = law.step(q, np.zeros(kin.nq), goal, 0.01)
    np.testing.assert_allclose(cmd.wrench, [0, 0, -3.0, 0, 0, 0], atol=1e-9)


def test_wrench_limit_scales_keeping_direction():
    rng = np.random.default_rng(1)
    for _ in range(200):
        f = rng.normal(0.0, 50.0, 6)
        out, s = scale_wrench(f, 10.0, 1.0)
        assert np.linalg.norm(out[:3]) <= 10.0 + 1e-9 and np.linalg.norm(out[3:]) <= 1.0 + 1e-9
        assert 0.0 <= s <= 1.0
        np.testing.assert_allclose(out, s * f)          # same direction, one factor
        if np.linalg.norm(f[:3]) <= 10.0 and np.linalg.norm(f[3:]) <= 1.0:
            assert s == 1.0


def test_joint_limits_scale_the_non_gravity_part():
    rng = np.random.default_rng(2)
    limit = np.full(9, 2.0)
    for _ in range(300):
        base = rng.uniform(-1.5, 1.5, 9)
        delta = rng.normal(0.0, 3.0, 9)
        tau, s = scale_into_limits(base, delta, limit)
        assert np.all(np.abs(tau) <= limit + 1e-12)
        np.testing.assert_allclose(tau, base + s * delta, atol=1e-12)
        # s is the largest feasible factor: a bit more would break a limit (or s == 1)
        if s < 1.0:
            assert np.any(np.abs(base + min(1.0, s + 1e-6) * delta) > limit)


def test_rate_limit_bounds_every_step():
    prev = np.zeros(9)
    target = np.linspace(-5.0, 5.0, 9)
    out, limited = rate_limit(target, prev, 0.5)
    assert limited and np.all(np.abs(out - prev) <= 0.5 + 1e-12)
    out, limited = rate_limit(prev + 0.1, prev, 0.5)
    assert not limited


def test_law_never_exceeds_the_servo_limits_under_any_command(kin):
    """Fuzz: random states, goals far away with huge stiffness and feed-forward: every
    output torque and every position-output current limit stays within the margin, the
    torque (torque output) changes at most torque_rate * dt per cycle and the pseudo-goal
    (position output) at most torque_rate * dt / k_s, the wrench within its limits."""
    cfg = LawConfig(torque_rate=50.0)
    rng = np.random.default_rng(11)
    lim = np.array([j.effort for j in kin.desc.joints]) * cfg.torque_margin
    for output in ("torque", "position"):
        law = HybridLaw(kin, cfg)
        for trial in range(20):
            q = kin.random_configuration(rng)
            law.reset(q)
            prev_tau = law.gravity.torques(q, law.payload)
            prev_q = q.copy()
            for _ in range(5):
                p = rng.uniform(-0.5, 0.5, 3)
                quat = rng.normal(size=4)
                quat /= np.linalg.norm(quat)
                goal = make_goal(kin, cfg, "base_link", p, quat,
                                 rng.uniform(0, cfg.max_linear_stiffness, 6) *
                                 np.r_[np.ones(3), np.full(3, 0.02)],
                                 rng.random(6) < 0.5,
                                 rng.normal(0, 5, 6) * np.r_[1, 1, 1, .1, .1, .1])
                dq = rng.normal(0.0, 2.0, kin.nq)
                cmd = law.step(q, dq, goal, 0.01, output=output)
                assert np.all(np.abs(cmd.tau) <= lim + 1e-9)
                assert np.all(cmd.effort_limit <= lim + 1e-9)
                assert output == "torque" or np.all(cmd.effort_limit > 0.0)  # 0 = default
                assert np.all(cmd.q_cmd >= kin.lower - 1e-12)
                assert np.all(cmd.q_cmd <= kin.upper + 1e-12)
                assert np.linalg.norm(cmd.wrench[:3]) <= cfg.max_force + 1e-9
                assert np.linalg.norm(cmd.wrench[3:]) <= cfg.max_moment + 1e-9
                if output == "torque":
                    assert np.all(np.abs(cmd.tau - prev_tau) <= 50.0 * 0.01 + 1e-9)
                else:
                    assert np.all(np.abs(cmd.q_cmd - prev_q) <= 50.0 * 0.01 / 20.0 + 1e-9)
                prev_tau, prev_q = cmd.tau, cmd.q_cmd


def test_enable_starts_from_gravity_and_the_present_pose(kin):
    law = HybridLaw(kin)
    q = _configs(kin, 1)[0]
    law.reset(q)
    goal = law.hold_goal(q, [500, 500, 500, 10, 10, 10])
    cmd = law.step(q, np.zeros(kin.nq), goal, 0.01, output="position")
    g = law.gravity.torques(q, law.payload)
    # the torque starts from gravity (changes by the rate limit at most), the pseudo-goal
    # from q itself: the arm neither drops nor jumps
    assert np.abs(cmd.tau - g).max() <= law.config.torque_rate * 0.01 + 1e-9
    assert np.abs(cmd.q_cmd - q).max() < 5e-3          # null-space posture only
    assert np.linalg.norm(kin.forward(cmd.q_cmd)[:3, 3] - kin.forward(q)[:3, 3]) < 2e-4


def test_rail_gets_no_torque(rail_kin):
    law = HybridLaw(rail_kin)
    assert law.na == 9 and law.arm_names[0] == "joint1"
    q = _configs(rail_kin, 1)[0]
    law.reset(q)
    cmd = law.step(q, np.zeros(rail_kin.nq), law.hold_goal(q, [300] * 3 + [5] * 3), 0.01)
    assert cmd.tau.shape == (9,) and cmd.q_cmd.shape == (9,)


@pytest.mark.parametrize("change, match", [
    (dict(frame="tool0"), "goal frame"),
    (dict(frame=""), "empty"),
    (dict(position=[math.nan, 0, 0]), "finite"),
    (dict(quat=[0, 0, 0, 0.9]), "quaternion norm"),
    (dict(stiffness=[-1, 0, 0, 0, 0, 0]), ">= 0"),
    (dict(stiffness=[1e5, 0, 0, 0, 0, 0]), "maxima"),
    (dict(position=[3.0, 0.0, 0.0]), "reach"),
    (dict(wrench=[0, 0, -500, 0, 0, 0]), "beyond the limits"),
])
def test_bad_goals_are_refused_with_the_reason(kin, change, match):
    args = dict(frame="base_link", position=[0.4, 0.0, 0.1], quat=[0, 0, 0, 1],
                stiffness=[300] * 3 + [5] * 3, axes=[False, False, True, False, False, False],
                wrench=[0.0] * 6)
    args.update(change)
    with pytest.raises(InvalidGoalError, match=match):
        make_goal(kin, LawConfig(), args["frame"], args["position"], args["quat"],
                  args["stiffness"], args["axes"], args["wrench"])


def test_config_and_state_validation(kin):
    with pytest.raises(ForceConfigError, match="torque_margin"):
        LawConfig(torque_margin=2.0)
    with pytest.raises(ForceConfigError, match="damping"):
        LawConfig(damping=(1.0, 2.0))
    with pytest.raises(ForceConfigError, match="posture"):
        HybridLaw(kin, LawConfig(posture=(0.0,) * 8))
    law = HybridLaw(kin)
    with pytest.raises(StateError):
        law.step(np.zeros(8), np.zeros(8), law.hold_goal(np.zeros(9), [1] * 6), 0.01)
    with pytest.raises(StateError):
        law.reset(np.full(9, math.nan))


def test_pose_error_is_x0_minus_x():
    r = pin.exp3(np.array([0.1, -0.2, 0.3]))
    w = np.array([0.01, 0.02, -0.03])
    e = pose_error(np.array([1.0, 2.0, 3.0]), pin.exp3(w) @ r, np.array([0.5, 2.0, 3.5]), r)
    np.testing.assert_allclose(e, [0.5, 0.0, -0.5, *w], atol=1e-12)


# --- wrench estimate -------------------------------------------------------------------

def test_estimate_recovers_a_known_wrench_and_tare_removes_a_bias(kin):
    rng = np.random.default_rng(5)
    est = WrenchEstimator(9)
    law = HybridLaw(kin)
    q = _configs(kin, 1)[0]
    j = kin.jacobian(q)
    g = law.gravity.torques(q, Payload())
    f_true = np.array([1.0, -2.0, -4.0, 0.05, 0.0, -0.1])
    bias = rng.normal(0.0, 0.05, 9)
    est.update(j, g + bias, g)
    est.tare()                                  # no contact: the residual is the bias
    for _ in range(60):
        out = est.update(j, g + bias + j.T @ f_true, g)
    # the damped inverse is nearly exact away from singularities
    np.testing.assert_allclose(out.wrench, f_true, atol=0.02 * np.abs(f_true).max())
    assert out.covariance.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(out.covariance) >= -1e-15)


def test_estimate_covariance_matches_monte_carlo(kin):
    """The covariance from the effort noise matches the spread of the raw estimates."""
    rng = np.random.default_rng(9)
    sigma = 0.03
    est = WrenchEstimator(9, EstimatorConfig(filter=1.0, effort_noise=sigma,
                                             friction_noise=0.0))
    q = _configs(kin, 1)[0]
    j = kin.jacobian(q)
    raws = np.array([est.update(j, rng.normal(0.0, sigma, 9), np.zeros(9)).raw
                     for _ in range(4000)])
    cov = est.update(j, np.zeros(9), np.zeros(9)).covariance
    np.testing.assert_allclose(np.diag(np.cov(raws.T)), np.diag(cov), rtol=0.1)


def test_to_tool_rotates_force_and_moment():
    r = pin.exp3(np.array([0.0, 0.0, math.pi / 2]))
    out, _ = to_tool(np.array([1.0, 0, 0, 0, 1.0, 0]), r)
    np.testing.assert_allclose(out, [0, -1.0, 0, 1.0, 0, 0], atol=1e-12)


# --- calibration -----------------------------------------------------------------------

def test_calibration_fit_recovers_scale_and_offset(kin, tmp_path):
    rng = np.random.default_rng(4)
    law = HybridLaw(kin)
    names = law.arm_names
    poses = [kin.random_configuration(rng) * 0.7 for _ in range(12)]
    model = np.array([law.gravity.torques(q, Payload()) for q in poses])
    scale = rng.uniform(0.9, 1.1, 9)
    offset = rng.normal(0.0, 0.02, 9)
    measured = model * scale + offset + rng.normal(0.0, 0.002, model.shape)
    cal = fit_calibration(names, model, measured)
    for i, n in enumerate(names):
        c = cal.joints[n]
        if c.identified:
            assert abs(c.scale - scale[i]) < 0.03, n
        assert abs(c.offset - offset[i]) < 0.01 or not c.identified, n
    assert not cal.joints["joint1"].identified     # vertical axis: no gravity torque
    assert cal.joints["joint2"].identified
    corrected = cal.correct(names, measured)
    rms_before = np.sqrt(np.mean((measured - model) ** 2))
    rms_after = np.sqrt(np.mean((corrected - model) ** 2))
    assert rms_after < 0.5 * rms_before
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    back = load_calibration(path, names)
    for n in names:
        assert back.joints[n].scale == pytest.approx(cal.joints[n].scale, abs=1e-6)


def test_calibration_errors(tmp_path):
    with pytest.raises(CalibrationError, match="at least 3"):
        fit_calibration(["a"], np.zeros((2, 1)), np.zeros((2, 1)))
    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: something_else\n")
    with pytest.raises(CalibrationError, match="not a torque calibration"):
        load_calibration(bad)
    bad.write_text("schema_version: 1\nkind: hyperarm_torque_calibration\n"
                   "joints: {jointX: {scale: 1.0, offset: 0.0}}\n")
    with pytest.raises(CalibrationError, match="jointX"):
        load_calibration(bad, ["joint1"])
    bad.write_text("schema_version: 1\nkind: hyperarm_torque_calibration\n"
                   "joints: {joint1: {scale: 7.0, offset: 0.0}}\n")
    with pytest.raises(CalibrationError, match="scale"):
        load_calibration(bad, ["joint1"])
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "missing.yaml")
    assert isinstance(TorqueCalibration({}).correct(["joint1"], np.array([1.0]))[0], float)


# --- parameters ------------------------------------------------------------------------

def test_every_parameter_is_documented_with_its_default():
    from pathlib import Path

    from hyperarm_control.force.parameters import PARAMETERS, build

    doc = (Path(__file__).resolve().parents[4] / "docs" / "force.md").read_text()
    for name, (default, _text, _check) in PARAMETERS.items():
        row = next((line for line in doc.splitlines() if line.startswith(f"| `{name}` |")), None)
        assert row is not None, f"docs/force.md does not list {name}"
        shown = row.split("|")[2].strip()
        if isinstance(default, float):
            assert float(shown) == default, (name, shown, default)
    law, est, ctl = build({n: d for n, (d, _t, _c) in PARAMETERS.items()})
    assert law == LawConfig(posture=(0.0,) * 9) and ctl.output == "position"
    with pytest.raises(ForceConfigError):
        build({"damping": [1.0, 2.0]})


def test_pure_force_goal_moves_the_pseudo_goal_at_bounded_speed(kin):
    """K = 0 with F_d on z (pure force control) in free space: the pseudo-goal (where the
    servos drive the tool) moves at most max_speed (over 1.2 s: the 5 N are reached at
    force_rate, 5 N/s, in 1 s)."""
    cfg = LawConfig()
    law = HybridLaw(kin, cfg)
    q = np.array([0.0, 0.5, 0.0, 0.6, 0.0, 0.5, 0.0, -1.0, 0.0])
    p, r = _pose(kin, q)
    quat = pin.Quaternion(r)
    goal = make_goal(kin, cfg, "base_link", p, [quat.x, quat.y, quat.z, quat.w],
                     [800, 800, 0, 20, 20, 20], [False, False, True, False, False, False],
                     [0, 0, -5.0, 0, 0, 0])
    law.reset(q)
    prev = p
    for _ in range(120):
        cmd = law.step(q, np.zeros(9), goal, 0.01, output="position")
        x = kin.forward(cmd.q_cmd)[:3, 3]
        assert np.linalg.norm(x - prev) <= cfg.max_speed * 0.01 * 1.05 + 1e-6
        prev = x
    assert prev[2] < p[2] - 0.005          # it does move down, towards the force


def test_joint_state_input_merges_by_name_and_drops_a_bad_message_whole():
    """The one joint_states handler of hybrid_force and hybrid_force_calibrate: merged by
    name; a malformed message changes nothing and warns once per reason (throttled)."""
    from sensor_msgs.msg import JointState

    from hyperarm_ik.ros_conversions import JointStateInput

    class Log:
        def __init__(self) -> None:
            self.lines: list[str] = []

        def warn(self, text: str) -> None:
            self.lines.append(text)

    log = Log()
    inp = JointStateInput(log)
    assert inp.merge(JointState(name=["joint1", "joint2"], position=[0.1, 0.2],
                                effort=[0.3, 0.4]))
    assert inp.merge(JointState(name=["gripper"], position=[0.5]))     # another driver's
    assert inp.ready(["joint1", "joint2", "gripper"], with_effort=["joint1"])
    assert not inp.ready(["joint1", "joint3"]) and not inp.ready(["gripper"], ["gripper"])
    bad = JointState(name=["joint1", "joint2"], position=[9.0])         # 1 value, 2 names
    assert not inp.merge(bad) and not inp.merge(bad)
    assert inp.cache.position == {"joint1": 0.1, "joint2": 0.2, "gripper": 0.5}
    assert len(log.lines) == 1 and "joint_states ignored" in log.lines[0], log.lines


def test_calibration_fit_does_not_trade_scale_for_offset_on_a_narrow_spread():
    """joint2 on the mock: ~3.3 N·m of gravity varying by +-0.07 over 3 poses, a 2 % torque
    constant error and quantized efforts (0.005 N·m). A plain two-parameter fit put the
    scale error into a 0.07 N·m offset; the regularised fit keeps the offset near 0 and
    finds the scale. A joint with no gravity torque (joint1) keeps scale 1."""
    x = np.array([[0.0, 3.25], [0.0, 3.33], [0.0, 3.40]])
    y = np.round(x / 1.02 / 0.005) * 0.005
    cal = fit_calibration(["joint1", "joint2"], x, y)
    j2 = cal.joints["joint2"]
    assert j2.identified and abs(j2.scale - 1 / 1.02) < 0.004 and abs(j2.offset) < 0.01, j2
    j1 = cal.joints["joint1"]
    assert not j1.identified and j1.scale == 1.0 and j1.offset == 0.0, j1


def test_friction_fit_and_compensation(tmp_path):
    """Coulomb friction: fitted per joint from moving samples against the model torques
    (median of sign(v) (corrected - model)), subtracted from a moving joint's effort only;
    a joint without enough moving samples keeps friction 0; the file keeps it."""
    from hyperarm_control.force.calibration import FRICTION_VELOCITY, JointCalibration, fit_friction

    rng = np.random.default_rng(3)
    names = ["joint1", "joint2", "joint3"]
    cal = TorqueCalibration({"joint2": JointCalibration(scale=1.1, offset=0.01)})
    fc = np.array([0.04, 0.03, 0.0])
    v = rng.uniform(-0.5, 0.5, (300, 3))
    v[:, 0] = np.where(np.abs(v[:, 0]) < 0.05, 0.1, v[:, 0])     # joint1 always moving
    v[:, 2] = 0.0                                                # joint3 never
    model = rng.normal(0.0, 1.0, (300, 3))
    true = model + np.sign(v) * fc + rng.normal(0.0, 0.003, (300, 3))
    measured = true.copy()
    measured[:, 1] = 1.1 * true[:, 1] + 0.01                    # joint2's scale and offset
    fitted = fit_friction(cal, names, model, measured, v)
    got = [fitted.joints[n].friction for n in names]
    assert abs(got[0] - 0.04) < 0.002 and abs(got[1] - 0.03) < 0.002 and got[2] == 0.0
    assert fitted.joints["joint2"].scale == 1.1                  # the rest kept
    save_calibration(fitted, tmp_path / "cal.yaml")
    back = load_calibration(tmp_path / "cal.yaml", names)
    assert back.joints["joint1"].friction == pytest.approx(got[0], abs=1e-6)
    slow = np.array([FRICTION_VELOCITY / 2, -0.3, 0.0])
    out = fitted.correct(names, np.array([1.0, 1.1 + 0.01, 1.0]), slow)
    assert np.allclose(out, [1.0, 1.0 + got[1], 1.0])              # only joint2 moves
    with pytest.raises(CalibrationError, match="friction"):
        fit_friction(cal, names, model[:, :2], measured, v)
    with pytest.raises(CalibrationError, match="friction"):
        JointCalibration(friction=-0.1)


def _enabled_controller(kin, q):
    from hyperarm_control.force.controller import ForceController
    ctl = ForceController(HybridLaw(kin))
    ctl.step(0.0, q, np.zeros(kin.nq), np.zeros(kin.nq))
    ctl.enable(True, 0.0)
    return ctl


def test_stale_states_make_it_passive_but_not_its_own_scheduling_gap(kin):
    """Joint states stopping make it passive within stale_timeout of the last one (checked
    every 10 ms, as the node does). A gap in its own checks longer than stale_timeout (the
    process itself not run: a loaded machine) is not judged as the states' silence: the
    states queued meanwhile are read first, the next check judges (before, such a starved
    node went passive with fresh states waiting)."""
    from hyperarm_control.force.controller import Mode
    q = _configs(kin, 1)[0]
    ctl = _enabled_controller(kin, q)
    for t in np.arange(0.01, 0.095, 0.01):
        assert ctl.check_stale(float(t)) is None
    event = ctl.check_stale(0.105)
    assert event is not None and event.kind == "stale" and ctl.mode is Mode.PASSIVE
    # starved for 0.3 s, then the queued state: still active
    ctl = _enabled_controller(kin, q)
    assert ctl.check_stale(0.05) is None
    assert ctl.check_stale(0.35) is None and ctl.mode is Mode.ACTIVE
    ctl.step(0.351, q, np.zeros(kin.nq), np.zeros(kin.nq))
    assert ctl.check_stale(0.36) is None and ctl.mode is Mode.ACTIVE
    # starved, and no state came meanwhile either: the next check judges
    ctl = _enabled_controller(kin, q)
    assert ctl.check_stale(0.05) is None
    assert ctl.check_stale(0.35) is None
    event = ctl.check_stale(0.36)
    assert event is not None and event.kind == "stale" and ctl.mode is Mode.PASSIVE
