"""ik_benchmark: Danko & Oh's Table II on our model, and further (prints its figures).

Sets (targets are tool0 poses in the root frame):
- random:      FK of uniform random joints within limits, cold start from q = 0.
- figure8:     a figure "8" in front of the arm, fixed orientation, each waypoint warm
               started from the last successful solution (the paper: "the previous joint
               angles serve as a close starting point"; q = 0 before the first success).
- figure8_tight, tight: the same at TRAC-IK's usual tolerance (1e-5 m, 1e-4 rad).
- figure8_wide: a second, larger 1,000-waypoint figure-8 (paths.FIGURE8_WIDE), also
               with the paper's solvers re-seeded from their returned joints after a
               failure (the old protocol), for comparison.
- near_limit:  FK of configurations with every joint within 5 % of a limit (cold).
- impossible:  reachable positions with orientations no configuration reaches (wrist point
               beyond 0.6034 m): time to an honest failure, ours vs TRAC-IK (5 ms, its
               default timeout, and 50 ms).
- unreachable: targets beyond the reach bound; time to a definite "no", and the default's
               closest configuration against the proven distance to the workspace.
- sensitivity: weighted_pinv's random-set success under K_w, the step rule and wrapping.
- collision:   collision-aware solves on the random set in a work cell (ignored, checked,
               avoided).
- rail_random: the random set on the rail variant (augmented, wln, default, TRAC-IK).
- rail_line:   Jia et al.'s experiment: a straight tool path with fixed orientation that
               needs the rail (joint motions plotted like their Fig. 5).
- service:     round trip of SolveIK from a Python client to the installed ik_service
               (two processes), p50/p95; and the same while a long (5 s) request runs.

Success by the paper's criterion: position within 1 mm and no joint outside its limits;
6-D success: also orientation within 1 deg. Everything is judged by our FK of the returned
joints, for every solver including the peers. Peers (benchmark-only dependencies, see
requirements-bench.txt): TRAC-IK (PyPI ``pytracik``) and ikpy.

Run: ``ros2 run hyperarm_ik ik_benchmark`` (``--help`` for options).
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pinocchio as pin

from hyperarm_description.urdf import generate_urdf

from ..kinematics import Kinematics, rotation_angle
from ..paths import FIGURE8, FIGURE8_WIDE, Figure8, hold_orientation
from ..solvers import make_solver
from . import ik_studies as studies

PAPER_POS = 1e-3                 # m, Danko & Oh's success criterion
SIX_D_ORI = math.radians(1.0)    # rad, our 6-D criterion
TIGHT = (1e-5, 1e-4)             # m, rad: TRAC-IK's usual tolerance
SOLVE_TOL = (1e-3, 1e-3)         # m, rad: the tolerances every solver is asked for


# --- solver adapters ---------------------------------------------------------------------
@dataclass
class Adapter:
    """A solver under test: ``solve(p, R, seed) -> q or None`` (None: it gave no joints)."""

    name: str
    solve: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray | None]
    count: int | None = None  # subsample size for slow solvers (None: the whole set)


def ours(kin: Kinematics, name: str, ptol: float, otol: float, timeout: float,
         count: int | None = None) -> Adapter:
    solver = make_solver(name, kin)

    def solve(p, r, seed):
        return solver.solve(p, r, seed, position_tolerance=ptol, orientation_tolerance=otol,
                            timeout=timeout).q
    return Adapter(name, solve, count)


def trac_ik(kin: Kinematics, eps: float, timeout: float) -> Adapter | str:
    """TRAC-IK (Speed) on the same URDF. eps bounds each twist component, so we ask for
    ptol / sqrt(3): its test then implies our norm test (m and rad alike)."""
    try:
        import pytracik
    except ImportError as exc:
        return f"pytracik not importable: {exc}"
    ik = pytracik.TRAC_IK(kin.root_frame, kin.desc.tool_frame, generate_urdf(kin.desc),
                          timeout, eps, pytracik.SolveType.Speed)
    if pytracik.get_num_joints(ik) != kin.nq:
        return f"pytracik chain has {pytracik.get_num_joints(ik)} joints, expected {kin.nq}"
    call = pytracik.ik

    def solve(p, r, seed):
        qu = pin.Quaternion(r)  # ~1 us, counted in TRAC-IK's time as our checks are in ours
        out = call(ik, seed, float(p[0]), float(p[1]), float(p[2]), qu.x, qu.y, qu.z, qu.w)
        return np.array(out[1:]) if out[0] >= 0 else None
    return Adapter("TRAC-IK", solve)


def ikpy_adapter(kin: Kinematics, count: int) -> Adapter | str:
    """ikpy (scipy least squares on the same URDF, full orientation)."""
    try:
        from ikpy.chain import Chain
    except ImportError as exc:
        return f"ikpy not importable: {exc}"
    if kin.variant != "arm":
        return "ikpy adapter built for the arm variant only"
    with tempfile.NamedTemporaryFile("w", suffix=".urdf", delete=False) as fh:
        fh.write(generate_urdf(kin.desc))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = Chain.from_urdf_file(fh.name, base_elements=[kin.root_frame])
        names = [link.name for link in full.links]
        end = names.index(f"{kin.desc.tool_frame}_joint") if \
            f"{kin.desc.tool_frame}_joint" in names else len(names) - 1
        links = full.links[:end + 1]
        mask = [link.name in kin.joint_names for link in links]
        chain = Chain(links, active_links_mask=mask)
    os.unlink(fh.name)
    idx = [i for i, m in enumerate(mask) if m]
    n = len(links)

    def solve(p, r, seed):
        init = np.zeros(n)
        init[idx] = seed
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = chain.inverse_kinematics(p, r, orientation_mode="all", initial_position=init)
        return np.asarray(sol)[idx]
    return Adapter("ikpy", solve, count)


# --- running a set -------------------------------------------------------------------------
@dataclass
class Run:
    set: str
    solver: str
    n: int = 0
    ok_paper: int = 0
    ok_6d: int = 0
    ok_tol: int = 0
    violations: int = 0
    no_answer: int = 0
    times: list[float] = field(default_factory=list)
    good_times: list[float] = field(default_factory=list)
    max_step: float = float("nan")
    qs: list[np.ndarray | None] = field(default_factory=list)
    reached: list[bool] = field(default_factory=list)

    def pct(self, k: int) -> str:
        return f"{100.0 * k / self.n:.1f}%" if self.n else "-"

    def ms(self, values: list[float], q: float) -> str:
        return f"{1e3 * float(np.percentile(values, q)):.3f}" if values else "-"


def evaluate(kin: Kinematics, run: Run, q: np.ndarray | None, p, r, tol) -> bool:
    """Judge q by our FK. Returns the paper's success."""
    run.n += 1
    if q is None:
        run.no_answer += 1
        return False
    t = kin.forward(q)
    perr = float(np.linalg.norm(t[:3, 3] - p))
    oerr = rotation_angle(r, t[:3, :3])
    within = kin.within_limits(q)
    run.violations += int(not within)
    ok = perr <= PAPER_POS and within
    run.ok_paper += int(ok)
    run.ok_6d += int(ok and oerr <= SIX_D_ORI)
    run.ok_tol += int(within and perr <= tol[0] and oerr <= tol[1])
    return ok


def run_cold(kin, adapter: Adapter, set_name, targets, tol) -> Run:
    run = Run(set_name, adapter.name)
    seed = np.zeros(kin.nq)
    for p, r in targets[:adapter.count]:
        t0 = time.perf_counter()
        q = adapter.solve(p, r, seed)
        dt = time.perf_counter() - t0
        ok = evaluate(kin, run, q, p, r, tol)
        run.times.append(dt)
        if ok:
            run.good_times.append(dt)
    return run


def run_track(kin, adapter: Adapter, set_name, targets, tol, reseed: str = "last_ok") -> Run:
    """Track ``targets`` warm started: from the last successful solution (``last_ok``, the
    paper's protocol as we read it) or from whatever the solver returned (``returned``)."""
    run = Run(set_name, adapter.name if reseed == "last_ok" else
              f"{adapter.name} (re-seeded from failures)")
    seed = np.zeros(kin.nq)
    prev_ok: np.ndarray | None = None
    steps = []
    for p, r in targets:
        t0 = time.perf_counter()
        q = adapter.solve(p, r, seed)
        dt = time.perf_counter() - t0
        ok = evaluate(kin, run, q, p, r, tol)
        run.times.append(dt)
        run.qs.append(None if q is None else np.array(q))
        run.reached.append(ok)
        if ok:
            run.good_times.append(dt)
            if prev_ok is not None:
                steps.append(float(np.abs(q - prev_ok).max()))
            prev_ok = np.array(q)
        else:
            prev_ok = None
        if q is not None and (ok or reseed == "returned"):
            seed = np.array(q)
    run.max_step = max(steps) if steps else float("nan")
    return run


# --- target sets ---------------------------------------------------------------------------
def random_targets(kin, n, rng):
    out = []
    for _ in range(n):
        t = kin.forward(rng.uniform(kin.lower, kin.upper))
        out.append((t[:3, 3].copy(), t[:3, :3].copy()))
    return out


def figure8_targets(kin, n, figure=FIGURE8):
    """The figure-8 (hyperarm_ik.paths, shared with the task ``figure8``): ``n`` waypoints,
    tool0 orientation of the ready pose (m)."""
    r = hold_orientation(kin)
    return [(p, r) for p in figure.points(n)]


def unreachable_targets(kin, n, rng):
    out = []
    for _ in range(n):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        p = kin.shoulder_origin + d * (kin.reach + rng.uniform(0.05, 0.5))
        r = pin.exp3(rng.normal(size=3))
        out.append((p, r))
    return out


def rail_line_targets(kin, n):
    """Jia et al.'s straight path, scaled to our arm: tool0 from (0.3, 0.05, 0.35) to
    (1.8, 0.15, 0.25) m in world, fixed orientation (the ready pose's)."""
    r = kin.forward(np.zeros(kin.nq))[:3, :3].copy()
    a, b = np.array([0.3, 0.05, 0.35]), np.array([1.8, 0.15, 0.25])
    return [(a + (b - a) * s, r) for s in np.linspace(0.0, 1.0, n)]


# --- service round trip ----------------------------------------------------------------
def _client_modes() -> list[tuple[str, type, str]]:
    """(label, executor class, how the client waits): the recommended way first."""
    from rclpy.executors import SingleThreadedExecutor
    out = [("SingleThreadedExecutor, spin_once loop", SingleThreadedExecutor, "spin_once"),
           ("SingleThreadedExecutor, spin_until_future_complete", SingleThreadedExecutor,
            "until")]
    try:
        from rclpy.experimental import EventsExecutor
        out.append(("EventsExecutor, spin_until_future_complete", EventsExecutor, "until"))
    except ImportError:
        pass
    return out


def wait_for_future(executor, future, timeout: float) -> None:
    """What we recommend to Python clients (docs/ik.md): spin_once until the future is
    done. With this rclpy (Jazzy wheels) ``spin_until_future_complete`` costs several ms
    more per call on a SingleThreadedExecutor. Returns at once when ``timeout`` s passed."""
    deadline = time.monotonic() + timeout
    while not future.done():
        left = deadline - time.monotonic()
        if left <= 0.0:
            return
        executor.spin_once(timeout_sec=min(left, 0.5))


def service_round_trip(count: int, timeout: float = 30.0) -> dict | str:
    """Start the installed ik_service in its own process (private ROS_DOMAIN_ID) and time
    ``count`` SolveIK calls (figure-8 waypoints, seeded with the previous solution) from this
    process, once per client mode (executor and way of waiting). Returns {mode: figures}."""
    try:
        import rclpy
        from ament_index_python.packages import get_package_prefix
        from hyperarm_description import contract
        from hyperarm_interfaces.srv import SolveIK
    except ImportError as exc:
        return f"ROS not importable: {exc}"
    exe = Path(get_package_prefix("hyperarm_ik")) / "lib" / "hyperarm_ik" / "ik_service"
    if not exe.exists():
        return f"{exe} not found (build the workspace)"
    domain = 150 + os.getpid() % 60
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen([str(exe)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    rclpy.init()
    node = rclpy.create_node("ik_benchmark_client", namespace=contract.DEFAULT_NAMESPACE)
    out: dict = {}
    try:
        cli = node.create_client(SolveIK, contract.SOLVE_IK)
        if not cli.wait_for_service(timeout_sec=timeout):
            return "ik_service did not come up"
        kin = Kinematics()
        targets = figure8_targets(kin, count)
        for ex_name, ex_cls, how in _client_modes():
            ex = ex_cls()
            ex.add_node(node)
            seed = np.zeros(kin.nq)
            rtts, solves, ok = [], [], 0
            for i, (p, r) in enumerate(targets):
                req = SolveIK.Request()
                req.target.header.frame_id = kin.root_frame
                req.target.pose.position.x, req.target.pose.position.y, \
                    req.target.pose.position.z = (float(v) for v in p)
                qu = pin.Quaternion(r)
                o = req.target.pose.orientation
                o.x, o.y, o.z, o.w = qu.x, qu.y, qu.z, qu.w
                req.seed.name = kin.joint_names
                req.seed.position = seed.tolist()
                req.position_tolerance, req.orientation_tolerance = SOLVE_TOL
                t0 = time.perf_counter()
                fut = cli.call_async(req)
                if how == "spin_once":
                    wait_for_future(ex, fut, timeout)
                else:
                    ex.spin_until_future_complete(fut, timeout_sec=timeout)
                dt = time.perf_counter() - t0
                resp = fut.result()
                if resp is None:
                    return f"no response to request {i} ({ex_name} client)"
                if i >= 10:  # the first calls include discovery and warm-up
                    rtts.append(dt)
                    solves.append(resp.solve_time)
                ok += int(resp.success)
                seed = np.array(resp.solution.position)
            ex.remove_node(node)
            ex.shutdown()
            out[ex_name] = {"n": len(rtts), "ok": ok, "count": count,
                            "p50": float(np.percentile(rtts, 50)),
                            "p95": float(np.percentile(rtts, 95)),
                            "solve_p50": float(np.percentile(solves, 50))}
        out["concurrent"] = _while_a_long_request_runs(node, cli, kin, targets, timeout)
        return out
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _solve_request(kin, p, r, seed, **fields):
    from hyperarm_interfaces.srv import SolveIK
    req = SolveIK.Request()
    req.target.header.frame_id = kin.root_frame
    req.target.pose.position.x, req.target.pose.position.y, req.target.pose.position.z = (
        float(v) for v in p)
    qu = pin.Quaternion(r)
    o = req.target.pose.orientation
    o.x, o.y, o.z, o.w = qu.x, qu.y, qu.z, qu.w
    req.seed.name = kin.joint_names
    req.seed.position = [float(v) for v in seed]
    req.position_tolerance, req.orientation_tolerance = SOLVE_TOL
    for k, v in fields.items():
        setattr(req, k, v)
    return req


def _while_a_long_request_runs(node, cli, kin, targets, timeout: float) -> dict:
    """Round trips of ordinary requests (spin_once client) while a legal 5 s request (the
    heuristic at a tolerance it never meets) runs on the service."""
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    # the target of the e2e test: the heuristic searches it for seconds from q = 0
    far = kin.forward(np.array([0.2, 0.5, -0.3, 0.4, 0.1, -0.5, 0.3, 0.2, -0.1]))
    p0, r0 = far[:3, 3], far[:3, :3]
    slow = cli.call_async(_solve_request(kin, p0, r0, np.zeros(kin.nq), solver="heuristic",
                                         timeout=5.0, position_tolerance=1e-300,
                                         orientation_tolerance=1e-300))
    ex.spin_once(timeout_sec=0.05)
    t_start = time.perf_counter()
    rtts, seed = [], np.zeros(kin.nq)
    for p, r in targets * 100:
        if slow.done():
            break
        t0 = time.perf_counter()
        fut = cli.call_async(_solve_request(kin, p, r, seed))
        wait_for_future(ex, fut, timeout)
        rtts.append(time.perf_counter() - t0)
        if fut.result() is not None:
            seed = np.array(fut.result().solution.position)
    during = time.perf_counter() - t_start
    wait_for_future(ex, slow, timeout)
    ex.remove_node(node)
    ex.shutdown()
    long_time = slow.result().solve_time if slow.result() is not None else float("nan")
    return {"n": len(rtts), "p50": float(np.percentile(rtts, 50)) if rtts else float("nan"),
            "p95": float(np.percentile(rtts, 95)) if rtts else float("nan"),
            "max": max(rtts) if rtts else float("nan"), "during": during,
            "long": long_time}


# --- output --------------------------------------------------------------------------------
HEADER = ("| set | solver | n | success (1 mm) | 6-D success (1 mm, 1 deg) | at asked tol | "
          "median ms | p95 ms | mean ms (successes) | limit violations | no answer | "
          "max joint step rad |")


def table(runs: list[Run]) -> str:
    lines = [HEADER, "|" + "---|" * 12]
    for r in runs:
        mean_good = f"{1e3 * float(np.mean(r.good_times)):.3f}" if r.good_times else "-"
        step = "-" if math.isnan(r.max_step) else f"{r.max_step:.4f}"
        lines.append(f"| {r.set} | {r.solver} | {r.n} | {r.pct(r.ok_paper)} | {r.pct(r.ok_6d)} | "
                     f"{r.pct(r.ok_tol)} | {r.ms(r.times, 50)} | {r.ms(r.times, 95)} | "
                     f"{mean_good} | {r.violations} | {r.no_answer} | {step} |")
    return "\n".join(lines)


def plots(outdir: Path, kin: Kinematics, fig8: list, track: dict[str, Run],
          rail: dict[str, Run] | None, rail_targets: list | None,
          cold: dict[str, Run]) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    names = list(track)
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 3.2), squeeze=False)
    ys = np.array([p[1] for p, _ in fig8])
    zs = np.array([p[2] for p, _ in fig8])
    for ax, name in zip(axes[0], names):
        ok = np.array(track[name].reached)
        ax.plot(ys[ok], zs[ok], ".", ms=2, color="tab:green", label="reached")
        ax.plot(ys[~ok], zs[~ok], "x", ms=4, color="tab:red", label="missed")
        ax.set_title(f"{name}: {100 * ok.mean():.1f}%", fontsize=9)
        ax.set_xlabel("y (m)")
        ax.set_aspect("equal")
    axes[0][0].set_ylabel("z (m)")
    axes[0][0].legend(fontsize=7, loc="lower left")
    fig.suptitle("figure-8 waypoints reached within 1 mm (warm start)", fontsize=10)
    fig.tight_layout()
    path = outdir / "ik_figure8_path.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path.name)

    for solver in [n for n in ("default", "weighted_pinv") if n in track]:
        qs = track[solver].qs
        arr = np.array([q if q is not None else np.full(kin.nq, np.nan) for q in qs])
        fig, ax = plt.subplots(figsize=(7, 3.4))
        for i, n in enumerate(kin.joint_names):
            ax.plot(np.degrees(arr[:, i]), lw=1, label=n)
        ax.axhline(np.degrees(kin.upper[0]), color="k", ls=":", lw=0.8)
        ax.axhline(np.degrees(kin.lower[0]), color="k", ls=":", lw=0.8)
        ax.set_xlabel("waypoint")
        ax.set_ylabel("joint angle (deg)")
        ax.set_title(f"joint trajectories along the figure-8 ({solver})", fontsize=10)
        ax.legend(fontsize=6, ncol=5, loc="upper right")
        fig.tight_layout()
        path = outdir / f"ik_figure8_joints_{solver}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path.name)

    if cold:
        fig, ax = plt.subplots(figsize=(6, 3.4))
        for name, run in cold.items():
            t = np.sort(np.array(run.times) * 1e3)
            ax.plot(t, np.linspace(0, 100, len(t)), label=name)
        ax.set_xscale("log")
        ax.set_xlabel("time per solve (ms, log)")
        ax.set_ylabel("% of targets")
        ax.set_title("random set: solve-time distribution (cold start)", fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        path = outdir / "ik_random_times.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path.name)

    if rail and rail_targets:
        fig, axes = plt.subplots(1, len(rail), figsize=(5 * len(rail), 3.4), squeeze=False)
        for ax, (name, run) in zip(axes[0], rail.items()):
            arr = np.array([q if q is not None else np.full(10, np.nan) for q in run.qs])
            for i, n in enumerate(["rail", "joint1", "joint2", "joint3", "joint4", "joint5"]):
                ax.plot(arr[:, i] if i == 0 else np.degrees(arr[:, i]) / 100.0, lw=1,
                        label=n + (" (m)" if i == 0 else " (deg/100)"))
            ok = np.array(run.reached)
            ax.set_title(f"{name}: straight path, {100 * ok.mean():.0f}% reached", fontsize=9)
            ax.set_xlabel("waypoint")
            ax.legend(fontsize=6)
        fig.tight_layout()
        path = outdir / "ik_rail_line_joints.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path.name)
    return written


def update_doc(path: Path, text: str) -> None:
    begin, end = "<!-- ik_benchmark:begin -->", "<!-- ik_benchmark:end -->"
    doc = path.read_text()
    if begin not in doc or end not in doc:
        raise SystemExit(f"{path} has no {begin} ... {end} block to update")
    head, rest = doc.split(begin, 1)
    _, tail = rest.split(end, 1)
    path.write_text(head + begin + "\n" + text + "\n" + end + tail)


# --- main -------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=1000, help="targets in random/figure8/tight")
    ap.add_argument("--slow-count", type=int, default=200,
                    help="subsample of the random sets for the heuristic solver")
    ap.add_argument("--ikpy-count", type=int, default=100, help="subsample for ikpy")
    ap.add_argument("--unreachable-count", type=int, default=200,
                    help="targets in the unreachable and impossible sets")
    ap.add_argument("--collision-count", type=int, default=1000,
                    help="random targets of the collision-aware study")
    ap.add_argument("--sensitivity-count", type=int, default=1000,
                    help="random targets of the weighted_pinv sensitivity study")
    ap.add_argument("--rail-count", type=int, default=300)
    ap.add_argument("--service-count", type=int, default=500, help="0 skips the service run")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--plots", type=Path, default=None, help="directory for PNG plots")
    ap.add_argument("--markdown", type=Path, default=None,
                    help="a markdown file whose ik_benchmark block is replaced by the results")
    ap.add_argument("--skip", nargs="*", default=[], help="set names to skip")
    ap.add_argument("--figure8", type=float, nargs=5, default=None,
                    metavar=("CX", "CY", "CZ", "HALF_WIDTH", "HALF_HEIGHT"),
                    help="the figure8 set's figure-8 (m, root frame; default: "
                         "hyperarm_ik.paths.FIGURE8): Table II's pattern row depends on it")
    args = ap.parse_args(argv)

    t_start = time.perf_counter()
    load_start = os.getloadavg()[0]
    kin = Kinematics()
    rng = np.random.default_rng(args.seed)
    random_set = random_targets(kin, args.count, rng)
    try:
        figure = FIGURE8 if args.figure8 is None else Figure8(
            center=tuple(args.figure8[:3]), half_width=args.figure8[3],
            half_height=args.figure8[4])
    except ValueError as exc:
        ap.error(f"--figure8: {exc}")
    fig8 = figure8_targets(kin, args.count, figure)
    notes: list[str] = []
    if figure != FIGURE8:
        notes.append(f"figure8 set on centre {figure.center} m, half width "
                     f"{figure.half_width} m, half height {figure.half_height} m "
                     f"(not paths.FIGURE8)")

    def peers(tol, timeout):
        out = []
        t = trac_ik(kin, tol[0] / math.sqrt(3.0), timeout)
        if isinstance(t, str):
            notes.append(f"TRAC-IK not run: {t}")
        else:
            out.append(t)
        return out

    paper = ["pinv", "weighted_pinv", "heuristic", "wln"]
    runs: list[Run] = []
    extra: list[str] = []  # further tables and lines of the studies
    cold: dict[str, Run] = {}
    track: dict[str, Run] = {}

    def report(run: Run) -> Run:
        runs.append(run)
        print(f"  {run.set:13s} {run.solver:14s} n={run.n:5d}  1mm {run.pct(run.ok_paper):>6s}  "
              f"6-D {run.pct(run.ok_6d):>6s}  median {run.ms(run.times, 50):>8s} ms  "
              f"p95 {run.ms(run.times, 95):>8s} ms  viol {run.violations}", flush=True)
        return run

    if "random" not in args.skip:
        print("random (cold start from q = 0):", flush=True)
        adapters = [ours(kin, "default", *SOLVE_TOL, 0.05)] + peers(SOLVE_TOL, 0.05)
        adapters += [ours(kin, n, *SOLVE_TOL, 3.0 if n == "heuristic" else 1.0,
                          args.slow_count if n == "heuristic" else None) for n in paper]
        ip = ikpy_adapter(kin, args.ikpy_count)
        if isinstance(ip, str):
            notes.append(f"ikpy not run: {ip}")
        else:
            adapters.append(ip)
        for a in adapters:
            cold[a.name] = report(run_cold(kin, a, "random", random_set, SOLVE_TOL))

    if "tight" not in args.skip:
        print("tight (random set at 1e-5 m, 1e-4 rad):", flush=True)
        for a in [ours(kin, "default", *TIGHT, 0.05)] + peers(TIGHT, 0.05):
            report(run_cold(kin, a, "tight", random_set, TIGHT))

    if "figure8" not in args.skip:
        print("figure8 (warm start from the previous solution):", flush=True)
        adapters = [ours(kin, "default", *SOLVE_TOL, 0.05)] + peers(SOLVE_TOL, 0.05)
        adapters += [ours(kin, n, *SOLVE_TOL, 1.0) for n in paper]
        for a in adapters:
            track[a.name] = report(run_track(kin, a, "figure8", fig8, SOLVE_TOL))
        print("figure8_tight (1e-5 m, 1e-4 rad):", flush=True)
        for a in [ours(kin, "default", *TIGHT, 0.05)] + peers(TIGHT, 0.05):
            report(run_track(kin, a, "figure8_tight", fig8, TIGHT))

    if "figure8_wide" not in args.skip:
        print("figure8_wide (second figure-8, warm start from the last success):", flush=True)
        wide = figure8_targets(kin, args.count, FIGURE8_WIDE)
        adapters = [ours(kin, "default", *SOLVE_TOL, 0.05)] + peers(SOLVE_TOL, 0.05)
        adapters += [ours(kin, n, *SOLVE_TOL, 1.0) for n in paper]
        for a in adapters:
            report(run_track(kin, a, "figure8_wide", wide, SOLVE_TOL))
        for n in ("pinv", "weighted_pinv"):
            report(run_track(kin, ours(kin, n, *SOLVE_TOL, 1.0), "figure8_wide", wide,
                             SOLVE_TOL, reseed="returned"))

    if "near_limit" not in args.skip:
        print("near_limit (every joint within 5 % of a limit, cold start):", flush=True)
        near = studies.near_limit_targets(kin, args.count, rng)
        for a in [ours(kin, "default", *SOLVE_TOL, 0.05)] + peers(SOLVE_TOL, 0.05):
            report(run_cold(kin, a, "near_limit", near, SOLVE_TOL))

    if "unreachable" not in args.skip:
        print("unreachable (time to a definite no):", flush=True)
        far = unreachable_targets(kin, args.unreachable_count, rng)
        adapters = [ours(kin, "default", *SOLVE_TOL, 0.05)] + peers(SOLVE_TOL, 0.05)
        adapters += [ours(kin, n, *SOLVE_TOL, 1.0, 50 if n == "heuristic" else None)
                     for n in paper]
        for a in adapters:
            report(run_cold(kin, a, "unreachable", far, SOLVE_TOL))
        c = studies.closest_study(kin, far)
        extra.append(
            f"- unreachable, default's closest configuration ({c['n']} targets): position "
            f"error / proven lower bound of the distance to the workspace: median "
            f"{c['median']:.3f}, p95 {c['p95']:.3f}, max {c['max']:.3f}; within 1.2x: "
            f"{c['within_1_2']}/{c['n']}; answers saying 'proven within 1.2x': "
            f"{c['proven']}/{c['n']} (the others say 'NOT proven the closest'); time p50 "
            f"{1e3 * c['time_p50']:.3f} ms")

    if "impossible" not in args.skip:
        print("impossible (reachable position, unreachable orientation):", flush=True)
        bad = studies.impossible_orientation_targets(kin, args.unreachable_count, rng)
        solver = make_solver("default", kin)

        def default_solve(p, r, q):
            return solver.solve(p, r, q, position_tolerance=SOLVE_TOL[0],
                                orientation_tolerance=SOLVE_TOL[1], timeout=0.1).q
        contenders = [("default (service default timeout 0.1 s)", default_solve)]
        for t_out in (0.005, 0.05):
            t = trac_ik(kin, SOLVE_TOL[0] / math.sqrt(3.0), t_out)
            if not isinstance(t, str):
                contenders.append((f"TRAC-IK (timeout {1e3 * t_out:g} ms)", t.solve))
        proven = sum(1 for p, r in bad if solver.solve(p, r).reachable is False)
        lines = ["| solver | n | median ms | p95 ms | max ms | wrongly 'solved' |",
                 "|---|---|---|---|---|---|"]
        for name, fn in contenders:
            times, wrong = studies.time_to_failure(kin, fn, bad)
            lines.append(f"| {name} | {len(times)} | {studies.ms(times, 50)} | "
                         f"{studies.ms(times, 95)} | {1e3 * max(times):.3f} | {wrong} |")
            print(f"  {name:40s} median {studies.ms(times, 50)} ms  p95 "
                  f"{studies.ms(times, 95)} ms", flush=True)
        extra.append("Time to an honest failure on impossible orientations (" + str(len(bad))
                     + f" targets; the default proved {proven} of them unreachable, "
                     "reachable=False):\n\n" + "\n".join(lines))

    if "collision" not in args.skip:
        print("collision (random set in a work cell: ignored, checked, avoided):", flush=True)
        lines, note = studies.collision_study(kin, random_set[:args.collision_count])
        print("\n".join("  " + line for line in lines), flush=True)
        extra.append("Collision-aware solves (default solver, random set, cold from q = 0, "
                     "50 ms, in ik_studies.BENCH_WORLD: table 0.2 m below the base, two "
                     "pegs, one pole; 'reached the pose' = within 1 mm / 1 deg):\n\n"
                     + "\n".join(lines) + "\n\n- " + note)

    if "sensitivity" not in args.skip:
        print("sensitivity (weighted_pinv on the random set):", flush=True)
        sub = random_set[:args.sensitivity_count]
        cols = studies.SENSITIVITY_COLUMNS
        lines = ["| variant (step halving reset each iteration unless said) | "
                 + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
        for name, counts in studies.sensitivity(kin, sub):
            pct = [studies.percent(k, len(sub)) for k in counts]
            lines.append(f"| {name} | " + " | ".join(pct) + " |")
            print(f"  {name:48s} " + " ".join(f"{v:>6s}" for v in pct), flush=True)
        extra.append(f"Sensitivity of weighted_pinv (random set, first {len(sub)} targets, "
                     "cold from q = 0, 1 mm and within limits, 500 iterations, 1 s):\n\n"
                     + "\n".join(lines))

    rail_track: dict[str, Run] = {}
    rail_line = None
    if "rail" not in args.skip:
        rkin = Kinematics(variant="rail_arm")
        print("rail_random (rail variant, cold start from q = 0):", flush=True)
        rset = random_targets(rkin, args.rail_count, rng)
        adapters = [ours(rkin, n, *SOLVE_TOL, 0.05 if n == "default" else 1.0)
                    for n in ("default", "augmented", "wln")]
        t = trac_ik(rkin, SOLVE_TOL[0] / math.sqrt(3.0), 0.05)
        if isinstance(t, str):
            notes.append(f"TRAC-IK (rail) not run: {t}")
        else:
            adapters.append(t)
        for a in adapters:
            report(run_cold(rkin, a, "rail_random", rset, SOLVE_TOL))
        print("rail_line (Jia's straight path, warm start):", flush=True)
        rail_line = rail_line_targets(rkin, 200)
        for n in ("augmented", "default"):
            rail_track[n] = report(run_track(rkin, ours(rkin, n, *SOLVE_TOL, 1.0), "rail_line",
                                             rail_line, SOLVE_TOL))

    service = None
    if args.service_count > 0 and "service" not in args.skip:
        print("service round trip (two processes):", flush=True)
        service = service_round_trip(args.service_count)
        if isinstance(service, str):
            notes.append(f"service round trip not measured: {service}")
            print("  " + service)
        else:
            conc = service.pop("concurrent")
            print(f"  while a long request runs: {conc['n']} ordinary requests, p50 "
                  f"{conc['p50'] * 1e3:.3f} ms, p95 {conc['p95'] * 1e3:.3f} ms, max "
                  f"{conc['max'] * 1e3:.3f} ms (long request: {conc['long']:.2f} s)")
            extra.append(f"- service_concurrent: {conc['n']} ordinary requests sent one after "
                         f"the other while a legal long request (heuristic, 5 s timeout) ran "
                         f"({conc['long']:.2f} s in all): round trip p50 "
                         f"{conc['p50'] * 1e3:.3f} ms, p95 {conc['p95'] * 1e3:.3f} ms, max "
                         f"{conc['max'] * 1e3:.3f} ms")
            for ex_name, f in service.items():
                print(f"  client {ex_name}: p50 {f['p50'] * 1e3:.3f} ms  p95 "
                      f"{f['p95'] * 1e3:.3f} ms  (solve p50 {f['solve_p50'] * 1e3:.3f} ms; "
                      f"{f['ok']}/{f['count']} solved)", flush=True)

    # ratios the targets are stated in
    def med(set_name, solver):
        for r in runs:
            if r.set == set_name and r.solver == solver and r.times:
                return float(np.median(r.times))
        return None
    summary = []
    for s in ("random", "tight"):
        a, b = med(s, "default"), med(s, "TRAC-IK")
        if a and b:
            summary.append(f"- {s}: default median / TRAC-IK median = {a / b:.2f}")
    m8 = med("figure8", "default")
    if m8:
        summary.append(f"- figure8: default median {m8 * 1e3:.3f} ms per solve")
    if service and not isinstance(service, str):
        for ex_name, f in service.items():
            summary.append(f"- service round trip, two processes, Python client: "
                           f"{ex_name} ({f['n']} calls after 10 warm-up): p50 "
                           f"{f['p50'] * 1e3:.3f} ms, p95 {f['p95'] * 1e3:.3f} ms (server-side "
                           f"solve p50 {f['solve_p50'] * 1e3:.3f} ms; {f['ok']}/{f['count']} "
                           f"solved)")
    elapsed = time.perf_counter() - t_start
    machine = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
               f"Python {platform.python_version()}, pinocchio {pin.__version__}, "
               f"load average {load_start:.2f} at the start, {os.getloadavg()[0]:.2f} at the end")
    text = "\n".join(
        [f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {machine}; "
         f"benchmark wall time {elapsed:.0f} s; command: `ik_benchmark "
         f"{' '.join(argv if argv is not None else sys.argv[1:])}`", "", table(runs), ""]
        + summary + [""] + [line for e in extra for line in (e, "")]
        + [f"- note: {n}" for n in notes])
    print()
    print(text)
    if args.plots:
        written = plots(args.plots, kin, fig8, track, rail_track, rail_line, cold)
        print(f"plots: {', '.join(str(args.plots / w) for w in written)}")
    if args.markdown:
        update_doc(args.markdown, text)
        print(f"updated {args.markdown}")


if __name__ == "__main__":
    main()
