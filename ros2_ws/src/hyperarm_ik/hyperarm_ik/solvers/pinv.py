"""Danko & Oh eqs. (1)-(3): pseudo-inverse Jacobian IK with step halving.

    q = q_previous + alpha * qdot                          (1)
    qdot = J^# [X0 - X]                                    (2)
    J^# = J^T (J J^T)^-1                                   (3)

Interpretations (the paper leaves them open; see docs/ik.md):
- [X0 - X] is the 6-D error [p0 - p; log3(R0 R^T)] (m, rad), both in the root frame, with
  J the LOCAL_WORLD_ALIGNED Jacobian; position_only uses the 3 position rows.
- J^# is the Moore-Penrose pseudo-inverse (SVD). It equals eq. (3) whenever J has full row
  rank, and stays defined at singular poses such as the ready pose q = 0 (rank 4), where
  (J J^T)^-1 does not exist.
- alpha starts at 1 on every iteration and is halved while the step would increase the norm
  of the error ("decreased if the solution begins to diverge"); below 2^-12 the solver
  stops (stuck in a local minimum or singularity). Other readings, for the sensitivity
  study of the benchmark (``step_rule``): "persist" keeps the last alpha for the next
  iteration (halving only, never growing back), "full" takes every step with alpha = 1.
- Joint limits are not considered (as in the paper); a result outside them is reported as a
  failure. Revolute joints are wrapped into (-pi, pi] at the end (same pose).
"""
from __future__ import annotations


import numpy as np

from ..errors import InvalidOptionError
from .base import Solver, task_error

__all__ = ["PinvSolver", "StepHalvingSolver"]


STEP_RULES = ("reset", "persist", "full")


class StepHalvingSolver(Solver):
    """Newton-like iteration q += alpha * direction with the paper's step halving.

    ``step_rule`` (see the module doc): "reset" (the paper as we read it), "persist" or
    "full"."""

    min_alpha = 2.0 ** -12
    step_rule = "reset"

    def _set_step_rule(self, rule: str) -> None:
        if rule not in STEP_RULES:
            raise InvalidOptionError(f"step_rule must be one of {', '.join(STEP_RULES)}, "
                                     f"got {rule!r}")
        self.step_rule = rule

    def _direction(self, q: np.ndarray, j: np.ndarray, e: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _start(self, q0: np.ndarray) -> np.ndarray:
        return q0

    def _admissible(self, q: np.ndarray) -> bool:
        """Whether a candidate configuration may be taken (subclasses restrict it)."""
        return True

    def _solve(self, p, r, q0, position_only, ptol, otol, deadline):
        kin = self.kin
        q = self._start(q0)
        rows = slice(0, 3) if position_only else slice(0, 6)
        pq, rq, j = kin.pose_jacobian_view(q)
        e = task_error(p, r, pq, rq, position_only)
        cost = float(np.linalg.norm(e))
        alpha0 = 1.0
        full = self.step_rule == "full"
        for it in range(self.max_iterations):
            if np.linalg.norm(e[:3]) <= ptol and (position_only or np.linalg.norm(e[3:]) <= otol):
                return q, it, ""
            if self._now() > deadline:
                return q, it, "timeout"
            dq = self._direction(q, j[rows], e)
            alpha = alpha0
            while True:
                qn = q + alpha * dq
                if self._admissible(qn):
                    pn, rn, jn = kin.pose_jacobian_view(qn)
                    en = task_error(p, r, pn, rn, position_only)
                    cn = float(np.linalg.norm(en))
                    if cn < cost or full:
                        break
                alpha *= 0.5
                if alpha < self.min_alpha:
                    return q, it + 1, "step halving stalled (local minimum or singularity)"
            if self.step_rule == "persist":
                alpha0 = alpha
            q, e, j, cost = qn, en, jn, cn
        return q, self.max_iterations, f"no convergence in {self.max_iterations} iterations"


def weighted_pinv_step(j: np.ndarray, winv: np.ndarray, e: np.ndarray) -> np.ndarray:
    """W^-1 J^T (J W^-1 J^T)^-1 e with diagonal W (``winv`` = diag of W^-1).

    The inverse is a pseudo-inverse, so singular J (e.g. the ready pose) stays defined.
    """
    jw = j * winv
    return jw.T @ (np.linalg.pinv(jw @ j.T) @ e)


class PinvSolver(StepHalvingSolver):
    """Pseudo-inverse Jacobian (Danko & Oh eqs. 1-3)."""

    name = "pinv"

    def __init__(self, kin, max_iterations: int = 500, step_rule: str = "reset") -> None:
        super().__init__(kin, max_iterations)
        self._set_step_rule(step_rule)

    def _direction(self, q, j, e):
        return np.linalg.pinv(j) @ e
