"""hyperarm's default IK solver: damped, weighted, limit-clamped Levenberg-Marquardt.

One iteration, with e = [p0 - p; s * log3(R0 R^T)] (s = ``orientation_scale`` m/rad,
position rows only when position_only), J the matching rows of the LOCAL_WORLD_ALIGNED
Jacobian (orientation rows scaled by s), W^-1 = diag(winv) and z a desired joint motion:

    lambda = gain * e.e + lambda0                     (analytic damping, after Sugihara)
    dq     = z + W^-1 J^T (J W^-1 J^T + lambda I)^-1 (e - J z),  |dq| <= max_step
    q      = clip(q + dq, lower, upper)

The 6 x 6 system is solved by Cholesky (eigenpy.LLT, pinocchio's own binding dependency).

i.e. dq minimises |J dq - e|^2 + lambda |dq - z|^2_W. Damping that shrinks with the error
gives Gauss-Newton speed near the solution and stays bounded at singular poses (q = 0).
Redundancy: z pulls joints out of the outer ``limit_margin`` of their range and, when a
``preferred`` posture is given, towards it; with z = 0 the step is the smallest joint motion,
which keeps warm-started tracking close to the seed. A joint held at a limit by the clip is
removed from the step (its W^-1 set to 0) and the step recomputed once (active set).

Cold starts (fixed arm): when tool0 is far (> 0.1 m) from the target and joint1 would have to
swing round (> 0.5 rad), joint1 is first turned to the target's azimuth (an exact one-joint
move); warm starts of tracking are never affected. Off for the rail variant, where it did
not pay off.

Restarts: an attempt stops when it stalls (error not reduced by 1 % over ``stall``
iterations) or after ``max_iterations``; the next starts from uniform random joints, until the
timeout. The best configuration seen is returned, with success computed from it.
Unreachable: a target farther from the shoulder than the sum of the link lengths (plus the
rail's travel) is out of reach for certain; the solver then returns at once with the
position-only best effort of a short attempt and says so.
Parameters are documented in docs/ik.md; units: m, rad, s (orientation_scale m/rad).
"""
from __future__ import annotations

import math
import time

import eigenpy
import numpy as np
import pinocchio as pin
from pinocchio import log3

from ..errors import InvalidOptionError
from .base import OUT_OF_REACH, Solver

__all__ = ["DefaultSolver"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class DefaultSolver(Solver):
    """Fast, limit-respecting, redundancy-aware IK with restarts (the service's default)."""

    name = "default"

    def __init__(self, kin, max_iterations: int = 60, orientation_scale: float = 0.5,
                 damping: float = 1e-8, max_step: float = 1.5, stall: int = 8,
                 limit_margin: float = 0.08, limit_gain: float = 0.5,
                 preferred: np.ndarray | None = None, preferred_gain: float = 0.0,
                 gain: float = 0.03, align_base: float | None = None,
                 align_distance: float = 0.1,
                 seed: int = 0) -> None:
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
        self.rng = np.random.default_rng(seed)
        self._eye3 = np.eye(3)
        self._eye6 = np.eye(6)
        self._ones = np.ones(kin.nq)
        # joints are surely inside their limits when |q_i| <= _rmin (fast path of the clip)
        self._rmin = kin.safe_range
        self._soft_rmin = float(max(0.0, min(np.min(-self._soft_lo), np.min(self._soft_hi))))

    # --- secondary motion ----------------------------------------------------------------
    def _z(self, q: np.ndarray) -> np.ndarray | None:
        z = None
        if self.limit_gain > 0.0:
            below = q < self._soft_lo
            above = q > self._soft_hi
            if below.any() or above.any():
                z = self.limit_gain * (np.where(below, self._soft_lo - q, 0.0)
                                       + np.where(above, self._soft_hi - q, 0.0))
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
        scaled = s != 1.0
        c = self.gain
        lo, hi, rmin = self._lo, self._hi, self._rmin
        soft_rmin = self._soft_rmin
        max_step2 = self.max_step * self.max_step
        need_limit_z = self.limit_gain > 0.0
        always_z = self.preferred is not None and self.preferred_gain > 0.0
        eye = self._eye3 if position_only else self._eye6
        best_q, best_cost = q, np.inf
        window_cost = np.inf
        llt = eigenpy.LLT
        concat = np.concatenate
        jacobian = pin.computeFrameJacobian
        oMf = data.oMf
        lst = q.tolist()
        qmin, qmax = min(lst), max(lst)
        for it in range(1, max_iter + 1):
            j = jacobian(model, data, q, fid, _LWA)
            m = oMf[fid]
            ep = p - m.translation
            perr = math.sqrt(ep @ ep)
            if position_only:
                cost = perr
                if perr <= ptol:
                    return q, cost, it - 1, None
                e = ep
                jt = j[:3]
                e2 = perr * perr
            else:
                eo = log3(r @ m.rotation.T)
                oerr = math.sqrt(eo @ eo)
                cost = perr + s * oerr
                if perr <= ptol and oerr <= otol:
                    return q, cost, it - 1, (perr, oerr)
                if scaled:
                    e = concat((ep, eo * s))
                    j[3:] *= s
                else:
                    e = concat((ep, eo))
                jt = j
                e2 = perr * perr + s * s * oerr * oerr
            if cost < best_cost:
                best_q, best_cost = q, cost
            if it % self.stall == 0:
                if best_cost > 0.99 * window_cost:
                    return best_q, best_cost, it, None
                window_cost = best_cost
                if time.perf_counter() > deadline:
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

    def _solve(self, p, r, q0, position_only, ptol, otol, deadline):
        kin = self.kin
        q = q0
        lst = q.tolist()
        if not (min(lst) >= -self._rmin and max(lst) <= self._rmin):
            q = np.minimum(np.maximum(q0, self._lo), self._hi)
        excess = kin.reach_excess(p)
        if excess > 0.0:
            qb, _, it, _ = self._attempt(p, r, q, True, ptol, otol, deadline, 15)
            return qb, it, (f"{OUT_OF_REACH}: the target is {excess:.3f} m beyond the "
                            f"{kin.reach:.3f} m reach of the arm; returning the closest "
                            f"configuration found")
        total = 0
        best_q, best_cost = q, np.inf
        attempts = 0
        while True:
            attempts += 1
            if self.align_base > 0.0:
                q = self._aligned(p, q)
            qa, cost, it, errs = self._attempt(p, r, q, position_only, ptol, otol, deadline,
                                               self.max_iterations)
            total += it
            if errs is not None or (position_only and cost <= ptol):
                note = "" if attempts == 1 else f"{attempts} attempts"
                return (qa, total, note) if errs is None else (qa, total, note, errs)
            if cost < best_cost:
                best_q, best_cost = qa, cost
            if time.perf_counter() > deadline:
                return best_q, total, (f"timeout after {attempts} attempts: best "
                                       f"approximate solution returned")
            q = self.rng.uniform(self._soft_lo, self._soft_hi)
