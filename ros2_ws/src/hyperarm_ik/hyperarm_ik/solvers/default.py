"""hyperarm's default IK solver: damped, weighted, limit-clamped Levenberg-Marquardt.

One iteration, with e = [p0 - p; s * log3(R0 R^T)] (s = ``orientation_scale`` m/rad,
position rows only when position_only), J the matching rows of the LOCAL_WORLD_ALIGNED
Jacobian (orientation rows scaled by s), W^-1 = diag(winv) and z a desired joint motion:

    lambda = gain * e.e + lambda0                     (analytic damping, after Sugihara)
    dq     = z + W^-1 J^T (J W^-1 J^T + lambda I)^-1 (e - J z),  |dq| <= max_step
    q      = clip(q + dq, lower, upper)

The 6 x 6 system is solved by Cholesky (eigenpy.LLT, pinocchio's own binding dependency),
in the equivalent unscaled form J W^-1 J^T + lambda S^-2 with S = diag(1, 1, 1, s, s, s),
the unscaled J and e (S (S M S + lambda I)^-1 S = (M + lambda S^-2)^-1): no row scaling.

i.e. dq minimises |J dq - e|^2 + lambda |dq - z|^2_W. Damping that shrinks with the error
gives Gauss-Newton speed near the solution and stays bounded at singular poses (q = 0).
Redundancy: z pulls joints out of the outer ``limit_margin`` of their range and, when a
``preferred`` posture is given, towards it; with z = 0 the step is the smallest joint motion,
which keeps warm-started tracking close to the seed. A joint held at a limit by the clip is
removed from the step (its W^-1 set to 0) and the step recomputed once (active set).

Cold starts (fixed arm): when the seed's tool pose is farther than ``align_distance``
(0.1 m, in the metric sqrt(|dp|^2 + s^2 theta^2), position only for position_only requests)
from the target, the first attempt starts from a precomputed table instead of the seed: FK
of ``start_table`` (65,536) configurations drawn uniformly within the soft limits by a fixed
RNG seed, built once per process (~0.3 s), binned by tool position in 0.1 m cubes; the start
is the entry of the target's cube minimising pose distance^2 + 0.01 |q|^2 (or the seed when
the cube is empty). A far target's solution therefore does not depend on the seed. A seed
within align_distance (warm starts, tracking) is used as is. Off by default for the rail
variant (its straight-line tracking got jerkier from table postures). Without a table start
(empty cube, restarts, ``start_table=0``) on the fixed arm: when tool0 is far (> 0.1 m) from
the target and joint1 would have to swing round (> 0.5 rad), joint1 is first turned to the
target's azimuth (an exact one-joint move); off for the rail variant, where it did not pay
off.

Restarts: an attempt stops when it stalls (error not reduced by 1 % over ``stall``
iterations) or after ``max_iterations``; the next starts from uniform random joints drawn
from a generator seeded by the request itself (target, seed, flags, tolerances, and the
solver's ``seed``), so the same request always gets the same answer. The search ends at
success, at the timeout, after ``max_attempts`` (0: no limit), or when it stalls:
``stall_attempts`` attempts ended at the best error (within 1 %), or ``stall_restarts``
restarts in a row did not improve it by 1 % (a probably unreachable target: said so, not
proven). The best configuration seen is returned, with success computed from it.
Unreachable (proven, :mod:`hyperarm_ik.workspace`): a target beyond the tool's reach bound
gets at once the configuration stretched towards it, with its distance ratio to the bound;
a pose whose wrist point is beyond the wrist's reach bound (an orientation that no
configuration reaches there) gets at once the best position-only configuration found.
Collisions (``collisions="avoid"``, with a collision model): an attempt that reaches the
pose in collision is pushed apart along the deepest contact's distance gradient projected
into the task's null space (``push_steps`` x ``push_step`` rad, LM after each), then the
search restarts from collision-free random joints, up to ``collision_attempts`` colliding
solutions; the answer names the pair if none is free.
Parameters are documented in docs/ik.md; units: m, rad, s (orientation_scale m/rad).
"""
from __future__ import annotations

import hashlib
import math
import struct

import eigenpy
import numpy as np
import pinocchio as pin
from pinocchio import log3

from ..errors import InvalidOptionError
from ..workspace import ReachBounds
from .base import ORIENTATION_OUT_OF_REACH, OUT_OF_REACH, Solver

__all__ = ["DefaultSolver"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
START_TABLE_SIZE = 65536  # configurations in the cold-start table of the fixed arm (0: none)
TABLE_CELL = 0.1         # m, edge of the position cubes the table is binned in
TABLE_RNG_SEED = 20261122
TABLE_POSTURE_WEIGHT = 0.01  # m^2/rad^2: among a cube's entries, prefer small |q|
STALL_ATTEMPTS = 3       # attempts ending at the best error (+1 %) that stop the search
STALL_RESTARTS = 16      # restarts in a row without a 1 % better error that stop it
_TABLES: dict[tuple, dict] = {}  # start tables by (size, scale, kinematics and soft limits)


class DefaultSolver(Solver):
    """Fast, limit-respecting, redundancy-aware IK with restarts (the service's default)."""

    name = "default"

    def __init__(self, kin, max_iterations: int = 60, orientation_scale: float = 0.5,
                 damping: float = 1e-8, max_step: float = 1.5, stall: int = 8,
                 limit_margin: float = 0.08, limit_gain: float = 0.5,
                 preferred: np.ndarray | None = None, preferred_gain: float = 0.0,
                 gain: float = 0.03, align_base: float | None = None,
                 align_distance: float = 0.1, start_table: int | None = None,
                 seed: int = 0, stall_attempts: int = STALL_ATTEMPTS,
                 stall_restarts: int = STALL_RESTARTS,
                 max_attempts: int = 0, closest_ratio: float = 1.2,
                 collision_attempts: int = 20, push_steps: int = 4,
                 push_step: float = 0.15) -> None:
        super().__init__(kin, max_iterations)
        for name, v in (("orientation_scale", orientation_scale), ("max_step", max_step)):
            if not np.isfinite(v) or v <= 0.0:
                raise InvalidOptionError(f"{name} must be > 0, got {v!r}")
        for name, v in (("damping", damping), ("limit_gain", limit_gain), ("gain", gain),
                        ("align_distance", align_distance),
                        ("preferred_gain", preferred_gain)):
            if not np.isfinite(v) or v < 0.0:
                raise InvalidOptionError(f"{name} must be >= 0, got {v!r}")
        if align_base is not None and (not np.isfinite(align_base) or align_base < 0.0):
            raise InvalidOptionError(f"align_base must be >= 0, got {align_base!r}")
        if start_table is not None and (isinstance(start_table, bool)
                                        or not isinstance(start_table, int) or start_table < 0):
            raise InvalidOptionError(f"start_table must be an integer >= 0, got {start_table!r}")
        for name, v in (("stall_attempts", stall_attempts), ("max_attempts", max_attempts),
                        ("stall_restarts", stall_restarts),
                        ("collision_attempts", collision_attempts), ("push_steps", push_steps),
                        ("seed", seed)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise InvalidOptionError(f"{name} must be an integer >= 0, got {v!r}")
        if not np.isfinite(closest_ratio) or closest_ratio < 1.0:
            raise InvalidOptionError(f"closest_ratio must be >= 1, got {closest_ratio!r}")
        if not 0.0 <= limit_margin < 0.5:
            raise InvalidOptionError(f"limit_margin must be in [0, 0.5), got {limit_margin!r}")
        if preferred is not None:
            preferred = np.asarray(preferred, dtype=float).reshape(-1)
            if preferred.shape != (kin.nq,) or not np.all(np.isfinite(preferred)):
                raise InvalidOptionError(f"preferred posture needs {kin.nq} finite values")
        self.s = float(orientation_scale)
        self.lambda0 = float(damping)
        self.gain = float(gain)
        if align_base is None:  # measured: helps the fixed arm, not the rail (see docs)
            align_base = 0.5 if kin.variant == "arm" else 0.0
        self.align_base = float(align_base)
        self.align_distance = float(align_distance)
        self._yaw = kin.joint_names.index("joint1")
        self.max_step = float(max_step)
        self.stall = int(stall)
        self.preferred = preferred
        self.preferred_gain = float(preferred_gain)
        span = kin.upper - kin.lower
        self._soft_lo = kin.lower + limit_margin * span
        self._soft_hi = kin.upper - limit_margin * span
        self.limit_gain = float(limit_gain)
        self._lo, self._hi = kin.lower, kin.upper
        self.seed = int(seed)
        self.stall_attempts = int(stall_attempts)
        self.stall_restarts = int(stall_restarts)
        self.max_attempts = int(max_attempts)
        self.closest_ratio = float(closest_ratio)
        if not np.isfinite(push_step) or push_step <= 0.0:
            raise InvalidOptionError(f"push_step must be > 0, got {push_step!r}")
        self.collision_attempts = max(1, int(collision_attempts))
        self.push_steps = int(push_steps)
        self.push_step = float(push_step)
        self.bounds = ReachBounds(kin)
        self._eye3 = np.eye(3)
        # S^-2, S = diag(1, 1, 1, s, s, s): the damping term of the unscaled system below
        self._sinv2 = np.diag([1.0, 1.0, 1.0] + [1.0 / (self.s * self.s)] * 3)
        self._ones = np.ones(kin.nq)
        # joints are surely inside their limits when |q_i| <= _rmin (fast path of the clip)
        self._rmin = kin.safe_range
        self._soft_rmin = float(max(0.0, min(np.min(-self._soft_lo), np.min(self._soft_hi))))
        if start_table is None:  # measured: helps the fixed arm; on the rail see docs
            start_table = START_TABLE_SIZE if kin.variant == "arm" else 0
        self._build_start_table(start_table)

    # --- cold starts from a table of (configuration -> tool pose) ---------------------------
    def _build_start_table(self, n: int) -> None:
        """FK of ``n`` configurations drawn uniformly within the soft limits (a fixed RNG
        seed: the table, hence every answer, is deterministic), binned by tool position in
        cubes of ``TABLE_CELL`` m. A pose is a feature vector f = [p, k R.ravel()] with
        k = s / sqrt(2): |f - f_i|^2 = |p - p_i|^2 + s^2 theta^2 to second order in the
        angle theta between R and R_i (the solver's own error metric). The lookup minimises
        |f - f_i|^2 + TABLE_POSTURE_WEIGHT |q_i|^2: central postures (fewer iterations,
        smoother tracking afterwards, measured) win over marginally nearer poses. Tables are shared
        (read only) by solvers of the same kinematics, soft limits, scale and size."""
        self._k = self.s / math.sqrt(2.0)
        self._cells: dict[tuple[int, int, int], tuple] = {}
        if n == 0:
            return
        kin = self.kin
        model = kin.model
        key = (n, self.s, np.concatenate(
            [model.jointPlacements[i].homogeneous.ravel() for i in range(model.njoints)]
            + [model.frames[kin.tool_id].placement.homogeneous.ravel(), self._soft_lo,
               self._soft_hi]).tobytes())
        cached = _TABLES.get(key)
        if cached is not None:
            self._cells = cached
            return
        qs = np.random.default_rng(TABLE_RNG_SEED).uniform(self._soft_lo, self._soft_hi,
                                                           (n, kin.nq))
        feats = np.empty((n, 12))
        data, fid = kin.data, kin.tool_id
        for i, q in enumerate(qs):
            pin.forwardKinematics(model, data, q)
            m = pin.updateFramePlacement(model, data, fid)
            feats[i, :3] = m.translation
            feats[i, 3:] = m.rotation.ravel()
        feats[:, 3:] *= self._k
        keys = np.floor(feats[:, :3] / TABLE_CELL).astype(int)
        order = np.lexsort(keys.T)
        keys, qs, feats = keys[order], qs[order], feats[order]
        bounds = np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1
        for lo, hi in zip(np.r_[0, bounds], np.r_[bounds, n]):
            fc = feats[lo:hi]
            # transposed copies: f @ F^T is the faster product for these short tables
            pen = TABLE_POSTURE_WEIGHT * np.einsum("ij,ij->i", qs[lo:hi], qs[lo:hi])
            self._cells[tuple(keys[lo].tolist())] = (
                qs[lo:hi], np.ascontiguousarray(fc.T), np.einsum("ij,ij->i", fc, fc) + pen,
                np.ascontiguousarray(fc[:, :3].T),
                np.einsum("ij,ij->i", fc[:, :3], fc[:, :3]) + pen)
        _TABLES[key] = self._cells

    def _cold_start(self, p: np.ndarray, r: np.ndarray, q: np.ndarray,
                    position_only: bool) -> tuple[np.ndarray, bool]:
        """(start, decided): the seed itself when its tool pose is within
        ``align_distance`` (in the metric above) of the target (warm starts, tracking);
        else the entry of the target's cell that minimises pose distance^2 + w |q|^2.
        ``decided`` is False only when the target's cell is empty (the seed is returned and
        the base alignment may still apply)."""
        kin = self.kin
        pin.forwardKinematics(kin.model, kin.data, q)
        m = pin.updateFramePlacement(kin.model, kin.data, kin.tool_id)
        px, py, pz = p.tolist()
        tx, ty, tz = m.translation.tolist()
        d2 = (px - tx) ** 2 + (py - ty) ** 2 + (pz - tz) ** 2
        if not position_only:  # |R - R_q|_F^2 = 2 (3 - <R, R_q>)
            d2 += 2.0 * self._k * self._k * (3.0 - float(np.vdot(r, m.rotation)))
        if d2 <= self.align_distance ** 2:
            return q, True
        h = TABLE_CELL
        cell = self._cells.get((math.floor(px / h), math.floor(py / h), math.floor(pz / h)))
        if cell is None:
            return q, False
        qs, ft, n2, pt, pn2 = cell  # ft, pt: features transposed (12, m), (3, m)
        if position_only:
            return qs[int(np.argmin(pn2 - 2.0 * (p @ pt)))], True
        f = np.concatenate((p, r.ravel() * self._k))
        return qs[int(np.argmin(n2 - 2.0 * (f @ ft)))], True

    # --- secondary motion ----------------------------------------------------------------
    def _z(self, q: np.ndarray) -> np.ndarray | None:
        z = None
        if self.limit_gain > 0.0:  # back into [soft_lo, soft_hi]; 0 for joints inside
            z = np.minimum(np.maximum(q, self._soft_lo), self._soft_hi)
            z -= q
            z *= self.limit_gain
        if self.preferred is not None and self.preferred_gain > 0.0:
            zp = self.preferred_gain * (self.preferred - q)
            z = zp if z is None else z + zp
        return z

    # --- base alignment (cold starts only) ------------------------------------------------
    def _aligned(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """q with joint1 turned so that tool0's azimuth about joint1's axis is the target's.

        Only when tool0 is more than ``align_distance`` m from the target and the azimuths
        differ by more than ``align_base`` rad: a cold start or a restart. Warm starts of
        tracking (targets millimetres away) are never touched, so this cannot make a joint
        jump along a path. It is an exact one-joint move (as in the heuristic search) that
        saves the LM iterations of swinging the arm round; it does not count as one.
        """
        kin = self.kin
        pin.forwardKinematics(kin.model, kin.data, q)
        m = kin.data.oMi[self._yaw + 1]
        wx, wy, wz = m.rotation[:, 2].tolist()  # revolute joints turn about local z
        ox, oy, oz = m.translation.tolist()
        tx, ty, tz = pin.updateFramePlacement(kin.model, kin.data,
                                              kin.tool_id).translation.tolist()
        px, py, pz = p.tolist()
        if (px - tx) ** 2 + (py - ty) ** 2 + (pz - tz) ** 2 < self.align_distance ** 2:
            return q
        ax, ay, az = px - ox, py - oy, pz - oz
        bx, by, bz = tx - ox, ty - oy, tz - oz
        da, db = ax * wx + ay * wy + az * wz, bx * wx + by * wy + bz * wz
        ax, ay, az = ax - da * wx, ay - da * wy, az - da * wz  # projections on the plane
        bx, by, bz = bx - db * wx, by - db * wy, bz - db * wz  # normal to the axis
        if min(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz) < 0.05 ** 2:
            return q  # target or tool near the axis: azimuth undefined
        sin = (by * az - bz * ay) * wx + (bz * ax - bx * az) * wy + (bx * ay - by * ax) * wz
        ang = math.atan2(sin, ax * bx + ay * by + az * bz)
        if abs(ang) <= self.align_base:
            return q
        out = q.copy()
        i = self._yaw
        out[i] = min(max(float(q[i]) + ang, float(self._lo[i])), float(self._hi[i]))
        return out

    # --- one attempt ---------------------------------------------------------------------
    def _attempt(self, p, r, q, position_only, ptol, otol, deadline, max_iter):
        """Iterate from q (within limits).

        Returns (q_best, cost_best, iterations, errors): ``errors`` is (position error,
        orientation error) evaluated at q_best when the tolerances were met, else None.
        """
        kin = self.kin
        model, data, fid = kin.model, kin.data, kin.tool_id
        s = self.s
        c = self.gain
        lo, hi, rmin = self._lo, self._hi, self._rmin
        soft_rmin = self._soft_rmin
        max_step2 = self.max_step * self.max_step
        need_limit_z = self.limit_gain > 0.0
        always_z = self.preferred is not None and self.preferred_gain > 0.0
        eye = self._eye3 if position_only else self._sinv2
        best_q, best_cost = q, np.inf
        window_cost = np.inf
        llt = eigenpy.LLT
        array = np.array
        px, py, pz = p.tolist()
        jacobian = pin.computeFrameJacobian
        oMf = data.oMf
        lst = q.tolist()
        qmin, qmax = min(lst), max(lst)
        for it in range(1, max_iter + 1):
            j = jacobian(model, data, q, fid, _LWA)
            m = oMf[fid]
            # errors on Python floats: cheaper than numpy calls on 3-vectors
            tx, ty, tz = m.translation.tolist()
            ex, ey, ez = px - tx, py - ty, pz - tz
            e2 = ex * ex + ey * ey + ez * ez
            perr = math.sqrt(e2)
            if position_only:
                cost = perr
                if perr <= ptol:
                    return q, cost, it - 1, None
                e = array((ex, ey, ez))
                jt = j[:3]
            else:
                ox, oy, oz = log3(r @ m.rotation.T).tolist()
                o2 = ox * ox + oy * oy + oz * oz
                oerr = math.sqrt(o2)
                cost = perr + s * oerr
                if perr <= ptol and oerr <= otol:
                    return q, cost, it - 1, (perr, oerr)
                e = array((ex, ey, ez, ox, oy, oz))  # unscaled: s enters through S^-2
                jt = j
                e2 += s * s * o2
            if cost < best_cost:
                best_q, best_cost = q, cost
            if it % self.stall == 0:
                if best_cost > 0.99 * window_cost:
                    return best_q, best_cost, it, None
                window_cost = best_cost
                if self._now() > deadline:
                    return best_q, best_cost, it, None
            lam = c * e2 + self.lambda0
            z = None
            if always_z or (need_limit_z and not (qmin >= -soft_rmin and qmax <= soft_rmin)):
                z = self._z(q)
            winv = None
            for _ in range(2):  # second pass only if the clip bound a joint
                jw = jt if winv is None else jt * winv
                a = jw @ jt.T
                a += lam * eye
                if z is None:
                    dq = jw.T @ llt(a).solve(e)
                else:
                    dq = jw.T @ llt(a).solve(e - jt @ z)
                    dq += z
                n2 = float(dq @ dq)
                if n2 > max_step2:
                    dq *= math.sqrt(max_step2 / n2)
                qn = q + dq
                lst = qn.tolist()
                qmin, qmax = min(lst), max(lst)
                if qmin >= -rmin and qmax <= rmin:
                    break  # inside the smallest |limit|: no per-joint test needed
                blocked = (qn < lo) | (qn > hi)
                if not blocked.any():
                    break
                qn = np.minimum(np.maximum(qn, lo), hi)
                lst = qn.tolist()
                qmin, qmax = min(lst), max(lst)
                if winv is not None:
                    break
                winv = np.where(blocked, 0.0, 1.0)
                if z is not None:
                    z = np.where(blocked, 0.0, z)
            q = qn
        return best_q, best_cost, max_iter, None

    # --- collision avoidance -------------------------------------------------------------
    def _collision_free(self, p, r, q, position_only, ptol, otol, deadline):
        """(q itself if collision-free, else a collision-free solution found by pushing q
        apart along the deepest contact's distance gradient projected into the task's null
        space (then re-converging by LM), or None; iterations spent)."""
        model, held = self.collision, self._held
        if not model.in_collision(q, held):
            return q, 0
        kin = self.kin
        total = 0
        rows = slice(0, 3) if position_only else slice(0, 6)
        for _ in range(self.push_steps):
            g = model.clearance_gradient(q, held)
            if g is None:
                return q, total
            j = kin.jacobian(q)[rows]
            dq = g[1] - np.linalg.pinv(j) @ (j @ g[1])  # null-space part of the gradient
            n = float(np.linalg.norm(dq))
            if n < 1e-9:
                return None, total
            q = np.minimum(np.maximum(q + dq * (self.push_step / n), self._lo), self._hi)
            qa, cost, it, errs = self._attempt(p, r, q, position_only, ptol, otol, deadline,
                                               self.max_iterations)
            total += it
            if not (errs is not None or (position_only and cost <= ptol)):
                return None, total  # pushed off the solution manifold
            if not model.in_collision(qa, held):
                return qa, total
            q = qa
            if self._now() > deadline:
                break
        return None, total

    def _free_start(self, rng: np.random.Generator, tries: int = 20) -> np.ndarray:
        """A random restart that is itself collision-free (a free start more often ends
        free), or the last draw after ``tries``."""
        for _ in range(tries):
            q = rng.uniform(self._soft_lo, self._soft_hi)
            if not self.collision.in_collision(q, self._held):
                return q
        return q

    # --- the request-seeded restart generator ------------------------------------------
    def _request_rng(self, p, r, q0, position_only, ptol, otol) -> np.random.Generator:
        """A generator seeded from the request itself (target, seed, flags, tolerances) and
        the solver's ``seed``: the same request always draws the same restarts, whatever
        was solved before (no state carried across calls)."""
        h = hashlib.blake2b(digest_size=16)
        for a in (p, r, q0):
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
        h.update(struct.pack("<?ddq", bool(position_only), float(ptol), float(otol),
                             self.seed))
        return np.random.default_rng(int.from_bytes(h.digest(), "little"))

    # --- proven-unreachable targets -----------------------------------------------------
    def _out_of_reach(self, p, r, q, verdict, ptol, otol, deadline):
        """The closest configuration of a target beyond the reach bound: the chain
        stretched towards it (exact where no limit binds), polished by a short
        position-only attempt; the note says whether it is proven within
        ``closest_ratio`` x the target's distance to the workspace."""
        qb = self.bounds.closest_stretch(p, q)
        perr = self.errors(qb, p, r)[0]
        lb = verdict.excess
        it = 0
        if perr > lb * (1.0 + 1e-9):  # a limit bound the stretch: polish it
            qa, _, it, _ = self._attempt(p, r, qb, True, ptol, otol, deadline, 30)
            pa = self.errors(qa, p, r)[0]
            if pa < perr:
                qb, perr = qa, pa
        head = f"{OUT_OF_REACH}: {verdict.reason}"
        if perr <= self.closest_ratio * lb:
            return qb, it, (f"{head}; returning the closest configuration: position error "
                            f"{perr:.4f} m, {perr / lb:.3f} x the target's distance to the "
                            f"workspace (at least {lb:.4f} m)")
        return qb, it, (f"{head}; the returned configuration is NOT proven the closest: "
                        f"position error {perr:.4f} m, while the workspace is at least "
                        f"{lb:.4f} m away")

    def _solve(self, p, r, q0, position_only, ptol, otol, deadline):
        q = q0
        lst = q.tolist()
        if not (min(lst) >= -self._rmin and max(lst) <= self._rmin):
            q = np.minimum(np.maximum(q0, self._lo), self._hi)
        verdict = self.bounds.position(p) if position_only else self.bounds.pose(p, r)
        if verdict.reason:
            if verdict.reason.startswith("the target"):
                return self._out_of_reach(p, r, q, verdict, ptol, otol, deadline)
            start = self._cold_start(p, r, q, True)[0] if self._cells else q
            qb, _, it, _ = self._attempt(p, r, start, True, ptol, otol, deadline,
                                         self.max_iterations)
            return qb, it, (f"{ORIENTATION_OUT_OF_REACH}: {verdict.reason}; returning the "
                            f"best position-only configuration found")
        total = 0
        best_q, best_cost = q, np.inf
        attempts = 0
        costs: list[float] = []  # final error of every attempt (stall test)
        collided = 0  # attempts that reached the pose in collision (collisions="avoid")
        colliding = None
        since_better = 0  # attempts since the best error last improved by 1 %
        rng = None
        decided = False  # the start of the first attempt was chosen by the table logic
        if self._cells:
            q, decided = self._cold_start(p, r, q, position_only)
        while True:
            attempts += 1
            if self.align_base > 0.0 and not decided:
                q = self._aligned(p, q)
            decided = False
            qa, cost, it, errs = self._attempt(p, r, q, position_only, ptol, otol, deadline,
                                               self.max_iterations)
            total += it
            if errs is not None or (position_only and cost <= ptol):
                if self._mode == "avoid":
                    free, it = self._collision_free(p, r, qa, position_only, ptol, otol,
                                                    deadline)
                    total += it
                    if free is None:  # reaches the pose, but collides: restart
                        colliding = qa
                        collided += 1
                        if collided >= self.collision_attempts or \
                                self._now() > deadline:
                            return colliding, total, (
                                f"no collision-free configuration found in {attempts} "
                                f"attempts ({collided} reached the pose in collision)")
                        if rng is None:
                            rng = self._request_rng(p, r, q0, position_only, ptol, otol)
                        q = self._free_start(rng)
                        continue
                    if free is not qa:
                        qa, errs = free, None
                note = "" if attempts == 1 else f"{attempts} attempts"
                return (qa, total, note) if errs is None else (qa, total, note, errs)
            costs.append(cost)
            since_better = 0 if cost < 0.99 * best_cost else since_better + 1
            if cost < best_cost:
                best_q, best_cost = qa, cost
            repeats = sum(1 for c in costs if c <= 1.01 * best_cost)
            if colliding is not None:  # the pose is reachable: only collisions are in the way
                repeats = since_better = 0
            if self.stall_attempts and repeats >= self.stall_attempts:
                return best_q, total, (f"search stalled: {repeats} of {attempts} attempts "
                                       f"ended at the same smallest error (within 1 %), so "
                                       f"the target is probably unreachable (not proven); "
                                       f"best approximate solution returned")
            if self.stall_restarts and since_better >= self.stall_restarts:
                return best_q, total, (f"search stalled: {since_better} restarts did not "
                                       f"improve the best error by 1 % ({attempts} attempts),"
                                       f" so the target is probably unreachable (not proven); "
                                       f"best approximate solution returned")
            if self.max_attempts and attempts >= self.max_attempts:
                return (best_q if colliding is None else colliding), total, (
                    f"gave up after {attempts} attempts (max_attempts); best approximate "
                    f"solution returned")
            if self._now() > deadline:
                if colliding is not None:
                    return colliding, total, (f"timeout after {attempts} attempts: no "
                                              f"collision-free configuration found")
                return best_q, total, (f"timeout after {attempts} attempts: best "
                                       f"approximate solution returned")
            if rng is None:
                rng = self._request_rng(p, r, q0, position_only, ptol, otol)
            q = rng.uniform(self._soft_lo, self._soft_hi)
