"""Chan's weighted least norm with joint-limit gradient weights (Jia et al. eqs. 5-7).

    qdot = W^-1 J^T (J W^-1 J^T)^-1 xdot                                   (5)
    W_i = 1 + |dH/dq_i|  if  Delta|dH/dq_i| >= 0  else 1                    (6)
    dH/dq_i = (qmax-qmin)^2 (2q - qmax - qmin) / (4 (qmax-q)^2 (q-qmin)^2)  (7)

Interpretations (see docs/ik.md):
- Position-level IK: xdot is the 6-D pose error [p0 - p; log3(R0 R^T)] and q += alpha*qdot,
  with the step halving of Danko & Oh eq. (1) (alpha halved while the error grows).
- Delta|dH/dq_i| is the change since the previous iteration; on the first iteration it is
  taken as 0 (so W_i = 1 + |dH/dq_i|).
- The seed is clipped into the open joint range (H is infinite on the limits), and a step
  that would leave the range is halved like a diverging one: the weights alone do not keep
  a discrete step inside the limits.
- Applies to both variants (the rail's H is in metres).
"""
from __future__ import annotations

import numpy as np

from .pinv import StepHalvingSolver, weighted_pinv_step

__all__ = ["WlnSolver", "limit_gradient"]


def limit_gradient(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """dH/dq of Chan's joint-limit criterion (Jia eq. 7); +-inf on the limits."""
    span = upper - lower
    with np.errstate(divide="ignore", invalid="ignore"):
        return span * span * (2.0 * q - upper - lower) / (
            4.0 * (upper - q) ** 2 * (q - lower) ** 2)


class WlnSolver(StepHalvingSolver):
    """Weighted least norm with joint-limit avoidance (Chan 1995, Jia et al. 2006)."""

    name = "wln"

    def __init__(self, kin, max_iterations: int = 500) -> None:
        super().__init__(kin, max_iterations)
        margin = 1e-6 * (kin.upper - kin.lower)
        self._lo = kin.lower + margin
        self._hi = kin.upper - margin
        self._prev: np.ndarray | None = None

    def _start(self, q0):
        self._prev = None
        return np.minimum(np.maximum(q0, self._lo), self._hi)

    def _admissible(self, q):
        return bool(np.all(q >= self._lo) and np.all(q <= self._hi))

    def _weights_inv(self, q: np.ndarray) -> np.ndarray:
        g = np.abs(limit_gradient(q, self.kin.lower, self.kin.upper))
        prev = g if self._prev is None else self._prev
        self._prev = g
        w = np.where(g - prev >= 0.0, 1.0 + g, 1.0)
        return 1.0 / w

    def _direction(self, q, j, e):
        return weighted_pinv_step(j, self._weights_inv(q), e)
