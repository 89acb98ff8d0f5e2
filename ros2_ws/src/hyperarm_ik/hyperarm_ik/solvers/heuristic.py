"""The heuristic per-joint search of Danko & Oh (after Marques et al.), steps 1-5.

1. FK: distance between tool0 and the goal.
2. Move each joint independently up and down by dtheta (start pi/4) without exceeding its
   limits, and evaluate the distance each time.
3. Pick the joint and direction with the smallest distance.
4. Apply it if it beats step 1 and go to 1; otherwise halve dtheta and go to 2.
5. Stop when the distance is below the threshold.

Interpretations (see docs/ik.md):
- "Distance" is the position distance |p0 - p| (m) for position_only requests; for full
  pose requests it is sqrt(|p0 - p|^2 + (rho * angle(R0, R))^2) with rho = 0.1 m/rad
  (1 deg ~ 1.7 mm), and step 5 requires both tolerances. (The plain sum |dp| + rho*angle
  has a kink at dp = 0 where no single-joint move improves the orientation: the search
  stalls there; the root-sum-square does not.)
- "Without exceeding the limits": a move is clipped at the limit (a joint already on its
  limit cannot move further), so every returned configuration is within limits.
- The solver gives up when dtheta < 1e-9 rad (no joint move improves) or at the timeout.
- All 2n candidate moves are evaluated in one vectorised step from a single FK: rotating
  joint i by d moves tool0 rigidly about joint i's axis (w_i through o_i), which is exactly
  what FK of the modified q gives (for the rail: a translation along its axis).
"""
from __future__ import annotations

import math

import numpy as np

from .base import Solver

__all__ = ["HeuristicSolver"]


class HeuristicSolver(Solver):
    """Per-joint greedy search with step halving (Danko & Oh, Marques et al.)."""

    name = "heuristic"

    def __init__(self, kin, max_iterations: int = 200_000, initial_step: float = math.pi / 4,
                 rho: float = 0.1, min_step: float = 1e-9) -> None:
        super().__init__(kin, max_iterations)
        self.initial_step = float(initial_step)
        self.rho = float(rho)
        self.min_step = float(min_step)
        self._joint_ids = list(range(1, kin.model.njoints))

    def _solve(self, p, r, q0, position_only, ptol, otol, deadline):
        kin = self.kin
        n = kin.nq
        q = kin.clip(q0)
        step = self.initial_step
        rev = kin.revolute
        signs = np.concatenate((np.ones(n), -np.ones(n)))
        idx = np.concatenate((np.arange(n), np.arange(n)))
        it = 0
        cost = None
        while it < self.max_iterations:
            it += 1
            pq, rq, j = kin.pose_jacobian_view(q)
            pq = pq.copy()
            dp = p - pq
            if position_only:
                perr, oerr = float(np.linalg.norm(dp)), 0.0
            else:
                c = (float(np.einsum("ij,ij->", r, rq)) - 1.0) * 0.5
                oerr = math.acos(min(1.0, max(-1.0, c)))
                perr = float(np.linalg.norm(dp))
            if cost is None:
                cost = math.hypot(perr, self.rho * oerr)
            if perr <= ptol and oerr <= otol:
                return q, it - 1, ""
            if self._now() > deadline:
                return q, it - 1, "timeout"
            while True:
                # Candidate moves of every joint up and down, clipped to the limits.
                target = np.minimum(np.maximum(q[idx] + signs * step, kin.lower[idx]),
                                    kin.upper[idx])
                delta = target - q[idx]
                costs = self._candidate_costs(p, r, pq, rq.copy(), j, idx, delta, rev,
                                              position_only)
                k = int(np.argmin(costs))
                if costs[k] < cost and delta[k] != 0.0:
                    q = q.copy()
                    q[idx[k]] = target[k]
                    cost = float(costs[k])
                    break
                step *= 0.5
                if step < self.min_step:
                    return q, it, "no joint move improves (local minimum)"
        return q, it, f"no convergence in {self.max_iterations} iterations"

    def _candidate_costs(self, p, r, pq, rq, j, idx, delta, rev, position_only):
        """Cost of each candidate (joint idx[k] moved by delta[k]) from one FK at q."""
        w = j[3:, idx].T  # angular columns = unit axes of revolute joints (root frame)
        origins = np.array([self.kin.data.oMi[i + 1].translation for i in range(self.kin.nq)])
        o = origins[idx]
        v = pq - o                                   # tool0 relative to each joint origin
        c = np.cos(delta)[:, None]
        s = np.sin(delta)[:, None]
        wv = np.einsum("ij,ij->i", w, v)[:, None]
        rot_v = v * c + np.cross(w, v) * s + w * wv * (1.0 - c)
        new_p = np.where(rev[idx][:, None], o + rot_v,
                         pq + j[:3, idx].T * delta[:, None])  # prismatic: translate
        costs = np.linalg.norm(p - new_p, axis=1)
        if position_only:
            return costs
        # angle(R0, Rot(w, d) R): trace(Rot(w,d) M) with M = R R0^T (root frame).
        m = rq @ r.T
        tr = np.trace(m)
        vee = np.array([m[1, 2] - m[2, 1], m[2, 0] - m[0, 2], m[0, 1] - m[1, 0]])
        wmw = np.einsum("ij,jk,ik->i", w, m, w)
        t = c[:, 0] * tr + s[:, 0] * (w @ vee) + (1.0 - c[:, 0]) * wmw
        t = np.where(rev[idx], t, tr)  # the rail does not rotate tool0
        ang = np.arccos(np.clip((t - 1.0) * 0.5, -1.0, 1.0))
        return np.hypot(costs, self.rho * ang)
