"""Target sets and studies of ik_benchmark beyond Table II (no ROS; prints nothing itself).

- near_limit_targets: FK of configurations with every joint within 5 % of a limit.
- impossible_orientation_targets: reachable tool positions with an orientation whose wrist
  point lies beyond the wrist's reach (no configuration reaches them).
- closest_study: on out-of-reach targets, the default's position error against the proven
  lower bound of the distance to the workspace.
- sensitivity: Table II's weighted pseudo-inverse under K_w, step rule and angle wrapping.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pinocchio as pin

from ..kinematics import Kinematics
from ..solvers import make_solver
from ..workspace import ReachBounds

__all__ = ["near_limit_targets", "impossible_orientation_targets", "closest_study",
           "sensitivity", "FIGURE8_WIDE"]

#: the second 1,000-waypoint figure-8 (m): larger and higher than the first, so that the
#: paper's solvers meet the joint limits along it
FIGURE8_WIDE = dict(center=(0.30, 0.0, 0.35), half_width=0.20, half_height=0.10)


def near_limit_targets(kin: Kinematics, n: int, rng: np.random.Generator, frac: float = 0.05):
    """FK of configurations whose every joint is within ``frac`` of its range from a limit."""
    span = kin.upper - kin.lower
    out = []
    for _ in range(n):
        side = rng.integers(0, 2, kin.nq)
        f = rng.uniform(0.0, frac, kin.nq)
        q = np.where(side == 1, kin.upper - f * span, kin.lower + f * span)
        t = kin.forward(q)
        out.append((t[:3, 3].copy(), t[:3, :3].copy()))
    return out


def impossible_orientation_targets(kin: Kinematics, n: int, rng: np.random.Generator):
    """Reachable positions (FK of random joints) with random orientations whose wrist point
    w = p + d9 R e_y is farther than 0.6034 m (l_1 + ... + l_8) from the base: the issue's
    example of a pose no configuration reaches."""
    b = ReachBounds(kin)
    plain = b.wrist_reach + b.a1
    out = []
    while len(out) < n:
        p = kin.forward(rng.uniform(kin.lower, kin.upper))[:3, 3].copy()
        r = pin.exp3(rng.normal(size=3) * 3.0)
        if np.linalg.norm(b.wrist_point(p, r)) > plain:
            out.append((p, r))
    return out


def closest_study(kin: Kinematics, targets) -> dict:
    """Default solver on out-of-reach targets: error / lower bound of the distance to the
    workspace, and how often the answer says it is proven within 1.2x."""
    s = make_solver("default", kin)
    ratios, proven, times = [], 0, []
    for p, r in targets:
        lb = s.bounds.position(p).excess
        res = s.solve(p, r, np.zeros(kin.nq))
        times.append(res.solve_time)
        ratios.append(res.position_error / lb)
        proven += int("NOT proven" not in res.message)
    a = np.array(ratios)
    return {"n": len(a), "median": float(np.median(a)), "p95": float(np.percentile(a, 95)),
            "max": float(a.max()), "within_1_2": int(np.sum(a <= 1.2)), "proven": proven,
            "time_p50": float(np.median(times))}


def _wpinv_success(kin, solver, targets, timeout: float) -> tuple[int, int]:
    """(successes with wrapping, successes without) at 1 mm and within limits."""
    wrap_ok = raw_ok = 0
    q0 = np.zeros(kin.nq)
    for p, r in targets:
        q = solver._solve(p, r, q0, False, 1e-3, 1e-3, time.perf_counter() + timeout)[0]
        q = np.asarray(q, dtype=float)
        perr = float(np.linalg.norm(kin.forward(q)[:3, 3] - p))
        if perr <= 1e-3:
            raw_ok += int(kin.within_limits(q))
            wrap_ok += int(kin.within_limits(kin.wrap(q)))
    return wrap_ok, raw_ok


def sensitivity(kin: Kinematics, targets, timeout: float = 1.0) -> list[tuple[str, int, int]]:
    """Random-set success of weighted_pinv (1 mm, within limits) for K_w, the step rule and
    angle wrapping: rows (variant, successes with wrapping, without)."""
    rows = []
    for k_w in (0.0, 1.0, 10.0, 100.0, 1000.0, 10000.0):
        s = make_solver("weighted_pinv", kin, k_w=k_w)
        rows.append((f"K_w = {k_w:g}, step halving reset each iteration", *_wpinv_success(
            kin, s, targets, timeout)))
    for rule, text in (("persist", "step halving, alpha kept"), ("full", "full steps")):
        s = make_solver("weighted_pinv", kin, step_rule=rule)
        rows.append((f"K_w = 1000, {text}", *_wpinv_success(kin, s, targets, timeout)))
    s = make_solver("pinv", kin)
    rows.append(("pinv (no weights), step halving reset", *_wpinv_success(kin, s, targets,
                                                                         timeout)))
    return rows


def percent(k: int, n: int) -> str:
    return f"{100.0 * k / n:.1f}%" if n else "-"


def ms(values, q: float) -> str:
    return f"{1e3 * float(np.percentile(values, q)):.3f}" if len(values) else "-"


def time_to_failure(kin: Kinematics, solve, targets) -> tuple[list[float], int]:
    """Times (s) of ``solve(p, R, seed) -> q or None`` on targets no configuration reaches,
    and how many answers (wrongly) met 1 mm / 1 deg."""
    times, wrong = [], 0
    seed = np.zeros(kin.nq)
    for p, r in targets:
        t0 = time.perf_counter()
        q = solve(p, r, seed)
        times.append(time.perf_counter() - t0)
        if q is not None:
            t = kin.forward(q)
            c = (np.trace(r.T @ t[:3, :3]) - 1.0) / 2.0
            wrong += int(np.linalg.norm(t[:3, 3] - p) <= 1e-3
                         and math.acos(min(1.0, max(-1.0, c))) <= math.radians(1.0))
    return times, wrong
