"""Danko & Oh eqs. (4)-(5): weighted pseudo-inverse Jacobian IK, K_w = 1000.

    qdot = W^-1 J^T (J W^-1 J^T)^-1 [X0 - X]               (4, as we read it)
    W = K_w (|q + qdot| - |q_previous|)                    (5)

Interpretations (see docs/ik.md):
- Eq. (4) as printed, W^-1 J^#T (J^# W^-1 J^#T)^-1, does not type-check (J^# is n x 6, W is
  n x n); it is read as the standard weighted pseudo-inverse with J, as in Jia eq. (5).
- Eq. (5) is read per joint, with the qdot "pre-calculated using the standard pseudo-inverse"
  (eq. 2) from the current q: W_i grows with how much that step would move joint i away from
  the middle of its range (|q| for the symmetric +-150 deg limits). A literal W can be zero
  or negative, which is no weight matrix; joints moving towards the middle keep weight 1:
  W_i = 1 + K_w * max(0, |q_i + qdot_i - m_i| - |q_i - m_i|), m_i the middle of the range.
- Step halving (alpha) and the stopping rules are those of eqs. (1)-(3) (see pinv.py).
- Limits are not enforced ("does not guarantee ... valid ranges"): violations are reported.
"""
from __future__ import annotations

import numpy as np

from ..errors import InvalidOptionError
from .pinv import StepHalvingSolver, weighted_pinv_step

__all__ = ["WeightedPinvSolver"]


class WeightedPinvSolver(StepHalvingSolver):
    """Weighted pseudo-inverse Jacobian (Danko & Oh eqs. 4-5)."""

    name = "weighted_pinv"

    def __init__(self, kin, max_iterations: int = 500, k_w: float = 1000.0,
                 step_rule: str = "reset") -> None:
        super().__init__(kin, max_iterations)
        if not np.isfinite(k_w) or k_w < 0.0:
            raise InvalidOptionError(f"k_w must be >= 0, got {k_w!r}")
        self.k_w = float(k_w)
        self._set_step_rule(step_rule)
        self._mid = 0.5 * (kin.lower + kin.upper)

    def _direction(self, q, j, e):
        qdot = np.linalg.pinv(j) @ e
        d = q - self._mid
        w = 1.0 + self.k_w * np.maximum(0.0, np.abs(d + qdot) - np.abs(d))
        return weighted_pinv_step(j, 1.0 / w, e)
