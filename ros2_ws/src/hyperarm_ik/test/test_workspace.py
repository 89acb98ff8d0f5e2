"""Exact reachability tests (workspace.py), honest failures and determinism of the default."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_ik.ik_core import IKCore, IKRequest
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.solvers import make_solver
from hyperarm_ik.workspace import ReachBounds

pytestmark = pytest.mark.core

ARM = Kinematics()
RAIL = Kinematics(variant="rail_arm")


@pytest.mark.parametrize("kin", [ARM, RAIL], ids=["arm", "rail_arm"])
def test_bounds_never_reject_a_reachable_pose(kin):
    b = ReachBounds(kin)
    rng = np.random.default_rng(3)
    worst_tool, worst_wrist = -np.inf, -np.inf
    for _ in range(3000):
        t = kin.forward(rng.uniform(kin.lower, kin.upper))
        p, r = t[:3, 3], t[:3, :3]
        assert not b.pose(p, r).reason
        worst_tool = max(worst_tool, b.position(p).excess)
        worst_wrist = max(worst_wrist, b._distance(b.wrist_point(p, r)) - b.wrist_reach)
    assert worst_tool <= 0.0 and worst_wrist <= 0.0
    # and they are not vacuous: random samples come within a few cm of them (the rail's
    # capsule about the segment joint1's origin travels along is looser than the arc)
    slack = 0.06 if kin.variant == "arm" else 0.15
    assert worst_tool > -slack and worst_wrist > -slack


def test_table_i_constants_and_the_wrist_point_is_o8():
    b = ReachBounds(ARM)
    assert b.wrist_reach == pytest.approx(0.5066, abs=1e-9)   # a2 + ... + a7
    assert b.wrist_reach + b.a1 == pytest.approx(0.6034, abs=1e-9)
    assert b.tool_reach == pytest.approx(0.5066 + 0.1902, abs=1e-9)
    np.testing.assert_allclose(b.hand, [0.0, -1.0, 0.0], atol=1e-12)
    rng = np.random.default_rng(4)
    for _ in range(20):
        t = ARM.forward(rng.uniform(ARM.lower, ARM.upper))
        w = b.wrist_point(t[:3, 3], t[:3, :3])
        np.testing.assert_allclose(w, ARM.data.oMi[9].translation, atol=1e-12)  # joint9's origin


def test_the_reach_bound_is_attained_by_the_stretched_chain():
    b = ReachBounds(ARM)
    rng = np.random.default_rng(5)
    for _ in range(50):
        az = rng.uniform(-2.0, 2.0)
        el = rng.uniform(-1.0, 1.0)
        p = 1.1 * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                            math.sin(el)])
        q = b.closest_stretch(p, np.zeros(9))
        assert ARM.within_limits(q)
        err = float(np.linalg.norm(ARM.forward(q)[:3, 3] - p))
        assert err == pytest.approx(b.position(p).excess, abs=1e-9)


def test_impossible_orientation_fails_at_once_and_says_why():
    s = make_solver("default", ARM)
    rng = np.random.default_rng(6)
    found = 0
    while found < 20:
        t = ARM.forward(rng.uniform(ARM.lower, ARM.upper))
        p = t[:3, 3]
        r = pin.exp3(rng.normal(size=3) * 3.0)
        if np.linalg.norm(s.bounds.wrist_point(p, r)) <= 0.6034:
            continue
        found += 1
        res = s.solve(p, r, np.zeros(9), timeout=5.0)
        assert not res.success and res.reachable is False
        assert "orientation out of reach" in res.message and "wrist point" in res.message
        assert res.iterations <= s.max_iterations  # one position-only attempt, no search
        assert ARM.within_limits(res.q)


def test_out_of_reach_closest_configuration_is_within_1_2x_or_says_not():
    s = make_solver("default", ARM)
    rng = np.random.default_rng(7)
    proven = 0
    for _ in range(60):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        p = d * rng.uniform(0.75, 1.3)
        v = s.bounds.position(p)
        if not v.reason:
            continue
        res = s.solve(p, pin.exp3(rng.normal(size=3)), np.zeros(9))
        assert not res.success and res.reachable is False
        assert ARM.within_limits(res.q)
        if "NOT proven the closest" in res.message:
            assert res.position_error > 1.2 * v.excess
        else:
            assert "returning the closest configuration" in res.message
            assert res.position_error <= 1.2 * v.excess
            proven += 1
    assert proven >= 40  # most directions can be stretched into


def test_same_request_same_answer_even_with_restarts():
    # max_iterations=4 forces restarts on most targets; nothing carries across calls
    kw = dict(max_iterations=4, max_attempts=40)
    a, b = make_solver("default", ARM, **kw), make_solver("default", ARM, **kw)
    rng = np.random.default_rng(8)
    targets = [ARM.forward(rng.uniform(ARM.lower, ARM.upper)) for _ in range(12)]
    first = [a.solve(t[:3, 3], t[:3, :3], np.zeros(9), timeout=30.0,
                     position_tolerance=1e-6, orientation_tolerance=1e-6) for t in targets]
    restarted = [r for r in first if "attempts" in r.message]
    assert len(restarted) >= 6, [r.message for r in first]
    for t, r1 in zip(reversed(targets), reversed(first)):  # other order, other instance
        for solver in (a, b):
            r2 = solver.solve(t[:3, 3], t[:3, :3], np.zeros(9), timeout=30.0,
                              position_tolerance=1e-6, orientation_tolerance=1e-6)
            np.testing.assert_array_equal(r1.q, r2.q)
            assert r1.message == r2.message and r1.iterations == r2.iterations


def test_service_core_answers_repeated_requests_identically():
    core = IKCore(ARM)
    rng = np.random.default_rng(9)
    reqs = []
    for _ in range(6):
        t = ARM.forward(rng.uniform(ARM.lower, ARM.upper))
        quat = pin.Quaternion(t[:3, :3])
        reqs.append(IKRequest(frame_id="base_link", position=t[:3, 3].tolist(),
                              orientation=[quat.x, quat.y, quat.z, quat.w],
                              position_tolerance=1e-7, orientation_tolerance=1e-7,
                              timeout=1.0))
    answers = [core.solve(r)[0].q for r in reqs]
    for r, q in zip(reqs * 2, answers * 2):
        np.testing.assert_array_equal(core.solve(r)[0].q, q)


def test_stall_test_ends_a_hopeless_search_long_before_the_timeout():
    s = make_solver("default", ARM)
    p = np.array([-0.77, 0.0, 0.0])  # behind the base, inside the bound, not reachable
    assert not s.bounds.position(p).reason
    res = s.solve(p, None, np.zeros(9), position_only=True, timeout=10.0)
    assert not res.success and res.reachable is None
    assert "search stalled" in res.message and "not proven" in res.message
    off = make_solver("default", ARM, stall_attempts=0, stall_restarts=0, max_attempts=60)
    res_off = off.solve(p, None, np.zeros(9), position_only=True, timeout=10.0)
    assert "max_attempts" in res_off.message
    assert res.iterations < res_off.iterations


def test_stall_options_are_validated():
    for bad in ({"stall_attempts": -1}, {"stall_restarts": 1.5}, {"max_attempts": True},
                {"closest_ratio": 0.9}):
        with pytest.raises(ValueError):
            make_solver("default", ARM, **bad)
