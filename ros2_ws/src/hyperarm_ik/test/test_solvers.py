"""Every IK solver: success paths, failure paths, honesty of the result, input checks."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_ik.errors import (IKError, InvalidOptionError, InvalidSeedError,
                                InvalidTargetError, UnknownSolverError,
                                UnsupportedVariantError)
from hyperarm_ik.kinematics import Kinematics, rotation_angle
from hyperarm_ik.solvers import SOLVERS, make_solver, solver_names
from hyperarm_ik.solvers.heuristic import HeuristicSolver
from hyperarm_ik.solvers.wln import limit_gradient

pytestmark = pytest.mark.core

ARM = Kinematics()
RAIL = Kinematics(variant="rail_arm")
KINS = {"arm": ARM, "rail_arm": RAIL}
CASES = [(v, n) for v in KINS for n in solver_names(v)]


def _target(kin, q):
    t = kin.forward(q)
    return t[:3, 3].copy(), t[:3, :3].copy()


def _check_honest(kin, res, p, r, ptol, otol, position_only=False):
    """The result's errors and success follow from its joints."""
    t = kin.forward(res.q)
    perr = float(np.linalg.norm(t[:3, 3] - p))
    oerr = rotation_angle(r, t[:3, :3])
    assert res.position_error == pytest.approx(perr, abs=1e-12)
    assert res.orientation_error == pytest.approx(oerr, abs=1e-9)
    within = kin.within_limits(res.q)
    assert res.violations == kin.limit_violations(res.q)
    expected = perr <= ptol and (position_only or oerr <= otol) and within
    assert res.success == expected
    assert ("not solved" in res.message) == (not res.success)


def _consistent_with_constraints(q):
    """q with alpha = joint2 = 0, beta = joint4 + joint5 = 0, and the augmented solver's
    rail_offset chosen so that d* equals q's rail value (Jia eq. 4 all satisfied)."""
    q = q.copy()
    names = RAIL.joint_names
    q[names.index("joint2")] = 0.0
    q[names.index("joint5")] = -q[names.index("joint4")]
    p, _ = _target(RAIL, q)
    offset = float(p[0] - RAIL.shoulder_origin[0]) - q[0]  # the arm's own reach along x
    return q, {"rail_offset": offset}


@pytest.mark.parametrize("variant,name", CASES)
def test_solver_reaches_a_nearby_target(variant, name):
    kin = KINS[variant]
    rng = np.random.default_rng(10)
    q_true = rng.uniform(kin.lower, kin.upper) * 0.6
    options = {}
    if name == "augmented":  # a pose consistent with the configuration constraints
        q_true, options = _consistent_with_constraints(q_true)
    p, r = _target(kin, q_true)
    seed = q_true + rng.normal(0.0, 0.03, kin.nq)
    solver = make_solver(name, kin, **options)
    res = solver.solve(p, r, seed, position_tolerance=1e-3, orientation_tolerance=1e-2,
                       timeout=5.0)
    assert res.success, res.message
    assert res.position_error <= 1e-3 and res.orientation_error <= 1e-2
    _check_honest(kin, res, p, r, 1e-3, 1e-2)


@pytest.mark.parametrize("variant,name", CASES)
def test_out_of_reach_target_fails_honestly(variant, name):
    kin = KINS[variant]
    p = kin.shoulder_origin + np.array([0.0, 0.3, kin.reach + 0.2])
    solver = make_solver(name, kin)
    res = solver.solve(p, np.eye(3), None, position_tolerance=1e-3, orientation_tolerance=1e-2,
                       timeout=0.3)
    assert not res.success
    assert res.position_error >= 0.2 - 1e-9
    assert "not solved" in res.message
    _check_honest(kin, res, p, np.eye(3), 1e-3, 1e-2)


def test_default_says_out_of_reach_at_once_with_a_best_effort():
    solver = make_solver("default", ARM)
    p = np.array([0.9, 0.2, 0.3])
    res = solver.solve(p, np.eye(3), None, timeout=1.0)
    assert res.reachable is False and "out of reach" in res.message
    assert res.solve_time < 0.5  # decided by the reach bound, not by the 1 s timeout
    # best effort: the arm points at the target (closest point at most the excess away)
    assert res.position_error <= ARM.reach_excess(p) + 0.05
    assert ARM.within_limits(res.q)


def test_pinv_reports_joint_limit_violations():
    q_true = np.zeros(9)
    q_true[[1, 3, 5]] = [0.4, math.radians(170), -0.6]  # joint4 beyond its 150 deg limit
    p, r = _target(ARM, q_true)
    res = make_solver("pinv", ARM).solve(p, r, q_true + 0.01, position_tolerance=1e-4,
                                         orientation_tolerance=1e-3)
    assert res.position_error <= 1e-4  # it converged ...
    assert "joint4" in res.violations  # ... outside the limits
    assert not res.success and "outside joint limits: joint4" in res.message


@pytest.mark.parametrize("name", ["default", "heuristic", "wln"])
def test_limit_respecting_solvers_never_return_violations(name):
    q_true = np.zeros(9)
    q_true[[1, 3, 5]] = [0.4, math.radians(170), -0.6]
    p, r = _target(ARM, q_true)
    seed = q_true.copy()  # even a seed outside the limits
    res = make_solver(name, ARM).solve(p, r, seed, position_tolerance=1e-3,
                                       orientation_tolerance=1e-2, timeout=0.5)
    assert res.violations == [] and ARM.within_limits(res.q)
    _check_honest(ARM, res, p, r, 1e-3, 1e-2)


@pytest.mark.parametrize("name", ["heuristic", "default", "pinv"])
def test_sub_second_timeout_is_honoured(name):
    # a reachable pose at a tolerance below floating-point resolution: it keeps searching
    p, r = _target(ARM, np.full(9, 0.3))
    res = make_solver(name, ARM).solve(p, r, None, position_tolerance=1e-300,
                                       orientation_tolerance=1e-300, timeout=0.05)
    assert not res.success
    assert res.solve_time < 0.05 + 0.1


@pytest.mark.parametrize("variant,count,ptol,otol", [("arm", 25, 1e-5, 1e-4),
                                                      ("rail_arm", 15, 1e-4, 1e-3)])
def test_default_solves_random_targets_cold_from_the_ready_pose(variant, count, ptol, otol):
    kin = KINS[variant]
    rng = np.random.default_rng(3)
    solver = make_solver("default", kin)
    for _ in range(count):
        p, r = _target(kin, rng.uniform(kin.lower, kin.upper))
        res = solver.solve(p, r, None, position_tolerance=ptol, orientation_tolerance=otol,
                           timeout=1.0)
        assert res.success, res.message
        _check_honest(kin, res, p, r, ptol, otol)


def test_position_only_reports_the_orientation_error_too():
    rng = np.random.default_rng(5)
    p, r = _target(ARM, rng.uniform(ARM.lower, ARM.upper))
    res = make_solver("default", ARM).solve(p, None, None, position_only=True,
                                            position_tolerance=1e-5)
    assert res.success and res.position_error <= 1e-5
    _check_honest(ARM, res, p, np.eye(3), 1e-5, 1e-3, position_only=True)
    assert res.orientation_error > 1e-3  # free orientation: identity is not implied


def test_warm_started_tracking_has_no_joint_jumps():
    solver = make_solver("default", ARM)
    q = np.zeros(9)
    q[[1, 3, 5]] = [0.5, -0.8, 0.6]
    p0, r = _target(ARM, q)
    seed = q
    for s in np.linspace(0.0, 0.1, 60):
        res = solver.solve(p0 + np.array([0.0, s, -0.5 * s]), r, seed,
                           position_tolerance=1e-5, orientation_tolerance=1e-4)
        assert res.success, res.message
        assert np.abs(res.q - seed).max() < 0.05
        seed = res.q


def test_preferred_posture_is_used_in_the_redundancy():
    q_pref = np.array([0.3, 0.4, -0.3, -0.5, 0.2, 0.6, -0.2, 0.3, 0.1])
    p, _ = _target(ARM, q_pref + np.array([0.1, -0.1, 0.1, 0, 0, 0, 0, 0, 0]))
    plain = make_solver("default", ARM).solve(p, None, None, position_only=True,
                                              position_tolerance=1e-5)
    pref = make_solver("default", ARM, preferred=q_pref, preferred_gain=0.3).solve(
        p, None, None, position_only=True, position_tolerance=1e-5)
    assert plain.success and pref.success
    assert np.linalg.norm(pref.q - q_pref) < 0.5 * np.linalg.norm(plain.q - q_pref)


def test_cold_start_base_alignment_is_exact_and_spares_warm_starts():
    from hyperarm_ik.solvers.default import DefaultSolver
    solver = DefaultSolver(ARM)
    q0 = np.zeros(9)
    p = np.array([-0.3, 0.3, 0.2])  # behind-left of the stretched arm
    q = solver._aligned(p, q0)
    assert q[0] == pytest.approx(math.atan2(0.3, -0.3))  # tool0 azimuth now the target's
    assert np.all(q[1:] == 0.0)
    near = ARM.forward(q0)[:3, 3] + np.array([0.0, 0.05, 0.0])  # a tracking step away
    assert solver._aligned(near, q0) is q0
    assert DefaultSolver(RAIL).align_base == 0.0  # off for the rail variant
    with pytest.raises(InvalidOptionError, match="align_base"):
        DefaultSolver(ARM, align_base=-1.0)


def test_cold_start_table_gives_a_nearby_configuration_and_spares_warm_starts():
    from hyperarm_ik.solvers.default import TABLE_CELL, TABLE_POSTURE_WEIGHT, DefaultSolver
    solver = DefaultSolver(ARM, start_table=4096)
    rng = np.random.default_rng(11)
    q0 = np.zeros(9)
    for _ in range(20):
        p, r = _target(ARM, rng.uniform(ARM.lower, ARM.upper))
        qt, decided = solver._cold_start(p, r, q0, False)
        if qt is q0:  # empty cell (or the ready pose is already close): seed kept
            continue
        assert decided
        pt, rt = _target(ARM, qt)
        assert np.all(np.abs(pt - p) <= TABLE_CELL * math.sqrt(3))  # same cell
        assert ARM.within_limits(qt) and np.all(qt >= solver._soft_lo)
        assert np.all(qt <= solver._soft_hi)
        # 6-D lookup: no entry of the cell scores better (pose distance^2 + w |q|^2)
        cell = solver._cells[tuple(math.floor(v / TABLE_CELL) for v in p)]
        f = np.concatenate((p, r.ravel() * solver._k))
        score = lambda fs, qs: np.sum((fs - f) ** 2, axis=-1) \
            + TABLE_POSTURE_WEIGHT * np.sum(qs ** 2, axis=-1)  # noqa: E731
        assert np.min(score(cell[1].T, cell[0])) == pytest.approx(
            score(np.concatenate((pt, rt.ravel() * solver._k)), qt))
    assert solver._cold_start(p, r, q0, False)[0] is not q0  # the last target: a far one
    # a target a tracking step away keeps the seed
    q = np.array([0.2, 0.4, -0.3, -0.5, 0.2, 0.6, -0.2, 0.3, 0.1])
    p, r = _target(ARM, q)
    for rot, position_only in ((r, False), (None, True)):
        start, decided = solver._cold_start(p + 0.02, rot, q, position_only)
        assert start is q and decided
    assert DefaultSolver(ARM, start_table=0)._cells == {}
    assert DefaultSolver(RAIL)._cells == {}  # off by default on the rail variant
    assert DefaultSolver(ARM, start_table=4096)._cells is solver._cells  # built once
    assert DefaultSolver(ARM, start_table=4096, limit_margin=0.1)._cells is not solver._cells
    with pytest.raises(InvalidOptionError, match="start_table"):
        DefaultSolver(ARM, start_table=-1)


@pytest.mark.parametrize("position_only", [False, True])
def test_far_targets_do_not_depend_on_the_seed(position_only):
    """A target far from the seed's tool pose starts from the table (deterministic), so
    two different far seeds give the same answer; success still follows from FK."""
    a, b = make_solver("default", ARM), make_solver("default", ARM)
    rng = np.random.default_rng(12)
    seeds = (np.zeros(9), np.array([-1.0, 0.8, 0.5, -0.7, 0.4, -1.2, 0.3, 0.9, -0.6]))
    tried = 0
    while tried < 5:
        p, r = _target(ARM, rng.uniform(ARM.lower, ARM.upper))
        rr = None if position_only else r
        if min(np.linalg.norm(_target(ARM, s)[0] - p) for s in seeds) <= 0.1:
            continue
        tried += 1
        ra = a.solve(p, rr, seeds[0], position_only=position_only, position_tolerance=1e-5,
                     orientation_tolerance=1e-4)
        rb = b.solve(p, rr, seeds[1], position_only=position_only, position_tolerance=1e-5,
                     orientation_tolerance=1e-4)
        assert ra.success and rb.success, (ra.message, rb.message)
        np.testing.assert_array_equal(ra.q, rb.q)
        _check_honest(ARM, ra, p, r if rr is not None else np.eye(3), 1e-5, 1e-4,
                      position_only)


def test_heuristic_candidate_moves_match_forward_kinematics():
    for kin in (ARM, RAIL):
        solver = HeuristicSolver(kin)
        rng = np.random.default_rng(6)
        q = rng.uniform(kin.lower, kin.upper) * 0.8
        p, r = _target(kin, rng.uniform(kin.lower, kin.upper))
        idx = np.concatenate((np.arange(kin.nq), np.arange(kin.nq)))
        delta = np.concatenate((np.full(kin.nq, 0.3), np.full(kin.nq, -0.2)))
        pq, rq, j = kin.pose_jacobian_view(q)
        costs = solver._candidate_costs(p, r, pq.copy(), rq.copy(), j, idx, delta,
                                        kin.revolute, False)
        for k in range(2 * kin.nq):
            qk = q.copy()
            qk[idx[k]] += delta[k]
            t = kin.forward(qk)
            expected = math.hypot(np.linalg.norm(p - t[:3, 3]),
                                  solver.rho * rotation_angle(r, t[:3, :3]))
            assert costs[k] == pytest.approx(expected, abs=1e-9)


def test_wln_gradient_is_the_derivative_of_chans_criterion():
    lo, hi = ARM.lower, ARM.upper

    def h(q):
        return np.sum((hi - lo) ** 2 / (4.0 * (hi - q) * (q - lo)))

    q = np.linspace(-2.0, 2.3, 9)
    eps = 1e-7
    num = np.array([(h(q + eps * np.eye(9)[i]) - h(q - eps * np.eye(9)[i])) / (2 * eps)
                    for i in range(9)])
    np.testing.assert_allclose(limit_gradient(q, lo, hi), num, rtol=1e-5)


def test_augmented_pulls_the_configuration_functions_to_their_targets():
    q_true = np.array([0.3, 0.2, 0.0, 0.3, 0.4, -0.4, 0.5, -0.3, 0.4, 0.1])
    q_true, options = _consistent_with_constraints(q_true)
    solver = make_solver("augmented", RAIL, **options)
    p, r = _target(RAIL, q_true)
    seed = q_true + np.random.default_rng(7).normal(0, 0.08, 10)  # constraints violated
    names = RAIL.joint_names
    assert abs(seed[names.index("joint2")]) > 0.01
    res = solver.solve(p, r, seed, position_tolerance=1e-5, orientation_tolerance=1e-4)
    assert res.success, res.message
    assert abs(res.q[names.index("joint2")]) < 1e-3
    assert abs(res.q[names.index("joint4")] + res.q[names.index("joint5")]) < 1e-3
    assert abs(res.q[0] - q_true[0]) < 1e-3


# --- validation -----------------------------------------------------------------------------
def test_unknown_solver_lists_the_valid_names():
    with pytest.raises(UnknownSolverError, match="valid: default, pinv"):
        make_solver("trac_ik", ARM)
    assert isinstance(UnknownSolverError("x"), IKError)


def test_augmented_needs_the_rail():
    with pytest.raises(UnsupportedVariantError, match="rail_arm"):
        make_solver("augmented", ARM)
    assert "augmented" not in solver_names("arm") and "augmented" in solver_names("rail_arm")


@pytest.mark.parametrize("name", sorted(set(SOLVERS) - {"augmented"}))
def test_malformed_requests_are_refused_with_a_precise_error(name):
    s = make_solver(name, ARM)
    p = np.array([0.3, 0.1, 0.2])
    with pytest.raises(InvalidTargetError, match="not finite"):
        s.solve(np.array([0.3, np.nan, 0.2]), np.eye(3))
    with pytest.raises(InvalidTargetError, match="needs 3 values"):
        s.solve(np.zeros(4), np.eye(3))
    with pytest.raises(InvalidTargetError, match="proper rotation"):
        s.solve(p, np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InvalidTargetError, match="proper rotation"):
        s.solve(p, np.eye(3) * 1.1)
    with pytest.raises(InvalidTargetError, match="rotation is not finite"):
        s.solve(p, np.full((3, 3), np.inf))
    with pytest.raises(InvalidTargetError, match="required unless position_only"):
        s.solve(p, None)
    with pytest.raises(InvalidSeedError, match="seed needs 9 values"):
        s.solve(p, np.eye(3), np.zeros(10))
    with pytest.raises(InvalidSeedError, match="joint3"):
        s.solve(p, np.eye(3), np.array([0, 0, np.inf, 0, 0, 0, 0, 0, 0.0]))
    for kw in ({"position_tolerance": 0.0}, {"orientation_tolerance": -1.0},
               {"timeout": float("nan")}):
        with pytest.raises(InvalidOptionError, match=next(iter(kw))):
            s.solve(p, np.eye(3), **kw)


def test_solver_options_are_validated():
    with pytest.raises(InvalidOptionError, match="max_iterations"):
        make_solver("pinv", ARM, max_iterations=0)
    with pytest.raises(InvalidOptionError, match="orientation_scale"):
        make_solver("default", ARM, orientation_scale=-1.0)
    with pytest.raises(InvalidOptionError, match="preferred posture"):
        make_solver("default", ARM, preferred=np.zeros(3))


def test_step_rule_of_the_paper_solvers():
    t = ARM.forward(np.full(9, 0.3))
    p, r = t[:3, 3].copy(), t[:3, :3].copy()
    for rule in ("reset", "persist", "full"):
        res = make_solver("weighted_pinv", ARM, step_rule=rule).solve(p, r, np.zeros(9),
                                                                       timeout=1.0)
        _check_honest(ARM, res, p, r, 1e-4, 1e-3)
    with pytest.raises(InvalidOptionError, match="step_rule"):
        make_solver("pinv", ARM, step_rule="halve")
    with pytest.raises(InvalidOptionError, match="k_w"):
        make_solver("weighted_pinv", ARM, k_w=-1.0)


@pytest.mark.parametrize("name", ["default", "pinv"])
def test_a_cpu_clock_timeout_is_not_cut_by_preemption(monkeypatch, name):
    """``clock="cpu"``: the timeout counts the solving thread's CPU time, so a solve whose
    wall clock jumps (the process preempted for a second) gives the same answer as an
    undisturbed one; with the wall clock the same jump cuts it at the first clock read."""
    import time

    kin = ARM
    # (the default without its start table: from q = 0 a solve reads the clock at all)
    solver = make_solver(name, kin, **({"start_table": 0} if name == "default" else {}))
    rng = np.random.default_rng(7)
    targets = [_target(kin, rng.uniform(kin.lower, kin.upper) * 0.8) for _ in range(12)]
    seed = np.zeros(kin.nq)

    def answers(clock):
        return [solver.solve(p, r, seed, timeout=0.5, clock=clock) for p, r in targets]

    calm = answers("cpu")
    real = time.perf_counter
    jumps = iter(range(10 ** 9))          # every read of the wall clock is a second later
    monkeypatch.setattr(time, "perf_counter", lambda: real() + 1.0 * next(jumps))
    jumped_cpu = answers("cpu")
    jumps = iter(range(10 ** 9))
    jumped_wall = answers("wall")
    monkeypatch.undo()
    # (a solve that used its whole 0.5 s of CPU is cut where the CPU clock's jitter says:
    # only the others are compared)
    for a, b in zip(calm, jumped_cpu):
        if "timeout" not in a.message and "timeout" not in b.message:
            assert a.success == b.success and np.array_equal(a.q, b.q), (a.message, b.message)
    assert sum("timeout" not in a.message for a in calm) >= 10
    # the wall clock's jump cut at least one solve that needed more than one clock read
    assert any(a.iterations != b.iterations or not np.array_equal(a.q, b.q)
               for a, b in zip(calm, jumped_wall))
    with pytest.raises(InvalidOptionError, match="clock"):
        solver.solve(*targets[0], seed, clock="sundial")
