"""Exact, cheap reachability tests derived from the DH table (no ROS).

Notation (standard DH, ``T_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``): o_i and
x_i, z_i are the origin and axes of DH frame i (frame 0 = base_link), so

    o_i - o_{i-1} = d_i z_{i-1} + a_i x_i,   |o_i - o_{i-1}| = l_i = sqrt(a_i^2 + d_i^2)

(x_i is perpendicular to z_{i-1}). Every l_i is a constant. The proofs are in docs/ik.md;
what they give, all in m:

- **Arc of o_1.** o_1 = o_0 + d_1 z_0 + a_1 x_1 with x_1 = Rz(theta_1 + q_1) x_0: o_1 lies
  on the arc A of radius a_1 about z_0 at height d_1 that joint 1's limits allow.
- **Tool point.** |p - o_1| <= l_2 + ... + l_9 (triangle inequality), so
  dist(p, A) - (l_2 + ... + l_9) > 0 proves p unreachable. It is a lower bound of the
  distance from p to the workspace, and equal to it wherever the chain 2..9 can be
  stretched towards p from the nearest point of A (closest_stretch() builds that pose).
- **Wrist point.** With a_9 = 0 the tool origin is o_9 = o_8 + d_9 z_8 whatever q_9, and
  z_8 = R Rx(alpha_9)^T e_z in terms of the tool rotation R: the wrist point
  w = p - d_9 R h (h = (0, sin alpha_9, cos alpha_9), the hand axis in tool0 coordinates;
  -y for Table I) is fixed by the target pose. |w - o_1| <= l_2 + ... + l_8, so
  dist(w, A) - (l_2 + ... + l_8) > 0 proves the pose unreachable (an orientation no
  configuration reaches at that position). For Table I: l_1 + ... + l_8 = 0.6034 m,
  l_2 + ... + l_8 = 0.5066 m, a_1 = 0.0968 m, d_9 = 0.1902 m.

On the rail variant o_0 moves along the rail; the arc is then replaced by the segment
o_0 travels along and the bounds by l_1 + ... (a capsule test: still exact, less tight).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .kinematics import Kinematics

__all__ = ["ReachBounds", "Verdict"]


@dataclass(frozen=True)
class Verdict:
    """Outcome of a reachability test: ``excess`` > 0 (m) proves the target unreachable."""

    excess: float
    reason: str           # "" when not proven unreachable


class ReachBounds:
    """Necessary conditions of reachability for one robot variant (see the module doc)."""

    def __init__(self, kin: Kinematics) -> None:
        self.kin = kin
        rows = [j.dh for j in kin.desc.joints]
        self.lengths = [math.hypot(r.a, r.d) for r in rows]
        self.a1, self.d1, self.theta1 = rows[0].a, rows[0].d, rows[0].theta
        j1 = kin.desc.joints[0]
        self.arc = (self.theta1 + j1.lower, self.theta1 + j1.upper)  # rad, about z_0
        last = rows[-1]
        # the wrist point exists when the tool origin does not depend on q_9 (a_9 = 0)
        self.has_wrist = abs(last.a) < 1e-12
        self.d9 = last.d
        self.hand = np.array([0.0, math.sin(last.alpha), math.cos(last.alpha)])
        self.tool_reach = float(sum(self.lengths[1:]))    # |p - o_1| bound
        self.wrist_reach = float(sum(self.lengths[1:-1]))  # |w - o_1| bound
        self.rail = kin.variant == "rail_arm"
        if self.rail:  # capsule tests about the segment o_0 travels along
            self.tool_reach = float(sum(self.lengths))
            self.wrist_reach = float(sum(self.lengths[:-1]))

    # --- distances -------------------------------------------------------------------------
    def _arc_distance(self, x: float, y: float, z: float) -> float:
        """Distance (m) from (x, y, z) in base_link to the arc of o_1 (exact)."""
        z -= self.d1
        rho = math.hypot(x, y)
        lo, hi = self.arc
        if hi - lo >= 2.0 * math.pi or rho == 0.0:
            delta = 0.0
        else:
            phi = math.atan2(y, x)
            mid = 0.5 * (lo + hi)
            off = (phi - mid + math.pi) % (2.0 * math.pi) - math.pi  # in [-pi, pi)
            delta = max(0.0, abs(off) - 0.5 * (hi - lo))
        a = self.a1
        return math.sqrt(max(0.0, rho * rho + a * a - 2.0 * rho * a * math.cos(delta) + z * z))

    def _distance(self, point: np.ndarray) -> float:
        """Distance from the set o_1 can take (fixed arm: the arc; rail: the segment of o_0)."""
        if self.rail:
            kin = self.kin
            u = kin.rail_direction
            s = float(np.dot(point - kin.shoulder_origin, u) / np.dot(u, u))
            lo, hi = kin.lower[0], kin.upper[0]
            s = min(max(s, lo), hi)
            return float(np.linalg.norm(point - kin.shoulder_origin - s * u))
        x, y, z = point.tolist()
        return self._arc_distance(x, y, z)

    def wrist_point(self, p: np.ndarray, r: np.ndarray) -> np.ndarray:
        """w = p - d_9 R h (m): the point the tool pose fixes whatever q_9."""
        return p - self.d9 * (r @ self.hand)

    # --- tests -----------------------------------------------------------------------------
    def position(self, p: np.ndarray) -> Verdict:
        """Tool position test: excess = dist(p, A) - (l_2 + ... + l_9)."""
        excess = self._distance(p) - self.tool_reach
        if excess > 0.0:
            where = "the rail's line" if self.rail else "the arc of joint 2's origin"
            return Verdict(excess, f"the target is {excess:.4f} m beyond the reach of the arm "
                                   f"({self.tool_reach:.4f} m from {where})")
        return Verdict(excess, "")

    def pose(self, p: np.ndarray, r: np.ndarray) -> Verdict:
        """Wrist-point test for a full pose (position test first)."""
        v = self.position(p)
        if v.reason or not self.has_wrist:
            return v
        w = self.wrist_point(p, r)
        excess = self._distance(w) - self.wrist_reach
        if excess > 0.0:
            return Verdict(excess, f"no configuration reaches this orientation at this "
                                   f"position: the wrist point (tool0 less "
                                   f"{self.d9:.4f} m along the hand axis) is {excess:.4f} m "
                                   f"beyond its {self.wrist_reach:.4f} m reach")
        return Verdict(excess, "")

    # --- the closest pose of an out-of-reach target ----------------------------------------
    def closest_stretch(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """A configuration with the chain 2..9 stretched from o_1 towards p (fixed arm):
        joint1 at p's azimuth, joint2 pitching x_2 onto p - o_1, joints 3..7 at 0 and joint8
        turning the hand axis onto x_7 (so the whole chain is one straight line). Angles are
        clipped into the limits; where no clip binds, the tool is at distance
        dist(p, A) - (l_2 + ... + l_9) from p, the lower bound itself. ``q`` supplies
        joint9 (which does not move the tool point)."""
        kin = self.kin
        out = np.array(q, dtype=float)
        if self.rail or not self.has_wrist:
            return kin.clip(out)
        model, data = kin.model, kin.data
        out[:8] = 0.0
        out[0] = math.atan2(p[1], p[0]) - self.theta1
        out[0] = -((-out[0] + math.pi) % (2.0 * math.pi) - math.pi)
        out = kin.clip(out)
        pin.forwardKinematics(model, data, out)
        m = data.oMi[2]  # joint2: origin o_1, z = z_1, x = x_2
        d = p - m.translation
        x2, z1 = m.rotation[:, 0], m.rotation[:, 2]
        out[1] += math.atan2(float(z1 @ np.cross(x2, d)), float(x2 @ d))
        out = kin.clip(out)
        pin.forwardKinematics(model, data, out)
        z7 = data.oMi[8].rotation[:, 2]   # joint8's axis z_7
        x7 = data.oMi[7].rotation[:, 0]   # x_7: link7's x axis
        z8 = data.oMi[9].rotation[:, 2]   # the hand axis z_8 (joint9's axis)
        out[7] += math.atan2(float(z7 @ np.cross(z8, x7)), float(z8 @ x7))
        return kin.clip(out)
