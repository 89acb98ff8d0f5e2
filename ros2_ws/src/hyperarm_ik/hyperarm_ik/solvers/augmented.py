"""Jia et al. eqs. (3)-(4): augmented Jacobian with configuration constraints (rail only).

    [xdot; fdot_C] = [J; J_C] qdot = J_E qdot                              (3)
    f_1C = alpha = q3,  f_2C = beta = q5 + q6,  f_3C = d = q1               (4)

solved with Chan's weighted least norm on J_E (eq. 5, weights of eqs. 6-7, see wln.py).

Interpretations (see docs/ik.md):
- Jia's chain counts the rail as q1, so in ours [rail, joint1..joint9]: d = rail,
  alpha (shoulder) = joint2, beta (elbow) = joint4 + joint5.
- Jia decouples a spherical wrist and controls the wrist point with a square 6 x 6 J_E. Our
  arm has no spherical wrist (joint7's axis is offset by a7 = 71.8 mm), so the full 6-D
  pose is the task: J_E is 9 x 10 and one degree of redundancy is left to the WLN weights.
  (With a square J_E the weights of eq. 5 cancel: W^-1 J_E^T (J_E W^-1 J_E^T)^-1 = J_E^-1.)
- The paper gives no desired values for f_C. We drive them towards "stretch the arm, move
  the rail to the best": alpha* = 0, beta* = 0 and d* = the target's projection on the rail
  minus ``rail_offset`` (0.4 m, about two thirds of the arm's stretched reach), clipped to
  the rail's travel. The constraint rows' error is f* - f(q).
- Success is judged on the pose only; the constraints are a preference the solver enforces,
  so poses that conflict with them may not be reached (reported honestly).
"""
from __future__ import annotations

import numpy as np

from .pinv import weighted_pinv_step
from .wln import WlnSolver

__all__ = ["AugmentedSolver"]


class AugmentedSolver(WlnSolver):
    """Augmented Jacobian + WLN for the rail variant (Jia et al. 2006)."""

    name = "augmented"
    variants = ("rail_arm",)

    def __init__(self, kin, max_iterations: int = 500, rail_offset: float = 0.4,
                 shoulder: float = 0.0, elbow: float = 0.0) -> None:
        super().__init__(kin, max_iterations)
        names = kin.joint_names
        self._i_rail = names.index("rail")
        self._i_alpha = names.index("joint2")
        self._i_beta = (names.index("joint4"), names.index("joint5"))
        jc = np.zeros((3, kin.nq))
        jc[0, self._i_alpha] = 1.0
        jc[1, self._i_beta[0]] = jc[1, self._i_beta[1]] = 1.0
        jc[2, self._i_rail] = 1.0
        self._jc = jc
        self.rail_offset = float(rail_offset)
        self._f_star = np.array([float(shoulder), float(elbow), 0.0])
        self._rail_dir = kin.rail_direction / np.linalg.norm(kin.rail_direction)

    def _rail_target(self, p: np.ndarray) -> float:
        """d* (m): the target's projection on the rail minus rail_offset, within travel."""
        d = float(np.dot(p - self.kin.shoulder_origin, self._rail_dir)) - self.rail_offset
        return min(max(d, self.kin.lower[self._i_rail]), self.kin.upper[self._i_rail])

    def _solve(self, p, r, q0, position_only, ptol, otol, deadline):
        self._f_star[2] = self._rail_target(p)
        return super()._solve(p, r, q0, position_only, ptol, otol, deadline)

    def _direction(self, q, j, e):
        f = self._jc @ q  # the constraint functions are linear in q
        je = np.vstack((j, self._jc))
        xe = np.concatenate((e, self._f_star - f))
        return weighted_pinv_step(je, self._weights_inv(q), xe)
