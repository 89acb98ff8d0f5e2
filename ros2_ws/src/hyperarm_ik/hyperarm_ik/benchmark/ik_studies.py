"""Target sets and studies of ik_benchmark beyond Table II (no ROS; prints nothing itself).

- near_limit_targets: FK of configurations with every joint within 5 % of a limit.
- impossible_orientation_targets: reachable tool positions with an orientation whose wrist
  point lies beyond the wrist's reach (no configuration reaches them).
- closest_study: on out-of-reach targets, the default's position error against the proven
  lower bound of the distance to the workspace.
- sensitivity: Table II's weighted pseudo-inverse under K_w, step rule and angle wrapping.
- collision_study: the default solver on the random set in a work cell, collisions
  ignored, checked and avoided.
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
           "sensitivity", "collision_study", "BENCH_WORLD"]



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


#: joint limits (deg, symmetric) the sensitivity study also judges the solutions against;
#: the paper does not state its limits (ours: +-150 deg, the MX servos' usual setting)
STUDY_LIMITS = (150.0, 165.0, 180.0)


def _wpinv_outcomes(kin, solver, targets, timeout: float) -> list[tuple[bool, bool, float]]:
    """Per target: (within 1 mm, ...) as (reached, raw q within +-150 deg, max |wrapped q|
    in deg) for the solver's unwrapped joints."""
    out = []
    q0 = np.zeros(kin.nq)
    for p, r in targets:
        q = solver._solve(p, r, q0, False, 1e-3, 1e-3, time.perf_counter() + timeout)[0]
        q = np.asarray(q, dtype=float)
        perr = float(np.linalg.norm(kin.forward(q)[:3, 3] - p))
        out.append((perr <= 1e-3, kin.within_limits(q),
                    float(np.degrees(np.max(np.abs(kin.wrap(q)))))))
    return out


SENSITIVITY_COLUMNS = (["wrapped, +-150 deg", "not wrapped, +-150 deg"]
                       + [f"wrapped, +-{lim:g} deg" for lim in STUDY_LIMITS[1:]])


def sensitivity(kin: Kinematics, targets, timeout: float = 1.0) -> list[tuple[str, list[int]]]:
    """Random-set success of weighted_pinv (1 mm, within limits) for K_w, the step rule,
    angle wrapping and the joint limits it is judged against: rows (variant, successes
    per SENSITIVITY_COLUMNS)."""
    variants = [(f"K_w = {k_w:g}", "weighted_pinv", {"k_w": k_w})
                for k_w in (0.0, 1.0, 10.0, 100.0, 1000.0, 10000.0)]
    variants += [("K_w = 1000, alpha kept across iterations", "weighted_pinv",
                  {"step_rule": "persist"}),
                 ("K_w = 1000, full steps (no halving)", "weighted_pinv", {"step_rule": "full"}),
                 ("pinv (no weights)", "pinv", {})]
    rows = []
    for label, name, opts in variants:
        res = _wpinv_outcomes(kin, make_solver(name, kin, **opts), targets, timeout)
        counts = [sum(1 for ok, _, m in res if ok and m <= 150.0 + 1e-9),
                  sum(1 for ok, raw, _ in res if ok and raw)]
        counts += [sum(1 for ok, _, m in res if ok and m <= lim + 1e-9)
                   for lim in STUDY_LIMITS[1:]]
        rows.append((label, counts))
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


#: the work cell of the collision benchmark: the mock's default cell (table 0.2 m below the
#: base, the source and destination pegs) plus the pole of the world schema's example
BENCH_WORLD = {
    "table_height": -0.20,
    "pegs": {"source": {"xy": [0.35, 0.12], "height": 0.08, "radius": 0.008},
             "destination": {"xy": [0.35, -0.12], "height": 0.08, "radius": 0.008}},
    "block": {"size": [0.04, 0.04, 0.03], "hole_radius": 0.010, "start": "source"},
    "poles": {"pole1": {"xy": [0.25, 0.0], "radius": 0.015, "height": 0.5}},
}


def collision_study(kin: Kinematics, targets, timeout: float = 0.05) -> tuple[list[str], str]:
    """Default solver in BENCH_WORLD, collisions ignored, checked and avoided, on two sets:
    ``targets`` (the random set: FK of uniform random joints, which often collide here) and
    as many targets made from collision-free random configurations (each reachable without
    collision). Returns the table's lines and a line on the cell."""
    from hyperarm_description.world import parse_world

    from ..collision import CollisionModel
    world = parse_world(BENCH_WORLD)
    model = CollisionModel(kin, world)
    s = make_solver("default", kin)
    s.use_collision_model(model)
    rng = np.random.default_rng(11)
    free_set, drawn, check_times = [], 0, []
    while len(free_set) < len(targets):
        q = rng.uniform(kin.lower, kin.upper)
        drawn += 1
        a = time.perf_counter()
        hit = model.in_collision(q)
        check_times.append(time.perf_counter() - a)
        if not hit:
            t = kin.forward(q)
            free_set.append((t[:3, 3].copy(), t[:3, :3].copy()))
    lines = ["| targets | collisions | n | success (1 mm, 1 deg, no collision) | reached the "
             "pose | of those in collision | median ms | p95 ms |",
             "|---|---|---|---|---|---|---|---|"]
    for set_name, tset in (("random", targets), ("from collision-free joints", free_set)):
        for mode in ("ignore", "check", "avoid"):
            ok = reached = colliding = 0
            times = []
            for p, r in tset:
                res = s.solve(p, r, np.zeros(kin.nq), position_tolerance=1e-3,
                              orientation_tolerance=1e-3, timeout=timeout, collisions=mode)
                times.append(res.solve_time)
                hit = res.contacts if mode != "ignore" else [str(c) for c in
                                                             model.check(res.q)]
                pose_ok = (res.position_error <= 1e-3
                           and res.orientation_error <= math.radians(1.0))
                reached += int(pose_ok)
                colliding += int(pose_ok and bool(hit))
                ok += int(pose_ok and not hit and not res.violations)
            lines.append(f"| {set_name} | {mode} | {len(tset)} | {percent(ok, len(tset))} | "
                         f"{percent(reached, len(tset))} | {colliding} | {ms(times, 50)} | "
                         f"{ms(times, 95)} |")
    note = (f"{len(free_set)} of {drawn} uniform random configurations "
            f"({percent(len(free_set), drawn)}) are collision-free in this cell; one full "
            f"check (self + world, {sum(model.pair_count.values())} pairs) takes "
            f"{ms(check_times, 50)} ms (median)")
    return lines, note
