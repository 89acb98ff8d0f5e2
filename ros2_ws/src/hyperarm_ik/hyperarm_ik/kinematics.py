"""Forward kinematics and Jacobians of tool0 on the pinocchio model (no ROS).

Units: q in rad (rail in m), positions in m. Poses are 4x4 homogeneous matrices in the
model's root frame (base_link, or world for the rail variant). Jacobians are 6 x nq,
rows [v; w] in LOCAL_WORLD_ALIGNED (tool0 origin, root-frame axes).

The ``*_view`` methods are the solvers' hot path: they return views into pinocchio's data
(valid until the next kinematics call on this object) and skip input validation.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from hyperarm_description.model import RobotDescription, load_description
from hyperarm_description.pinocchio_model import build_model

from .errors import InvalidSeedError

__all__ = ["Kinematics", "rotation_error", "rotation_angle"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def rotation_error(r_target: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Rotation vector (rad, root frame) that turns ``r`` into ``r_target``: log3(Rt R^T)."""
    return pin.log3(r_target @ r.T)


def rotation_angle(r_target: np.ndarray, r: np.ndarray) -> float:
    """Angle (rad, in [0, pi]) between two rotation matrices.

    |Rt - R|_F^2 = 8 sin^2(angle / 2): accurate for small angles, unlike acos of the trace.
    """
    d = (r_target - r).ravel()
    return 2.0 * math.asin(min(1.0, math.sqrt(float(d @ d) / 8.0)))


class Kinematics:
    """FK and Jacobian of ``tool0`` for one robot variant."""

    def __init__(self, desc: RobotDescription | None = None, variant: str = "arm") -> None:
        self.desc = desc if desc is not None else load_description(variant=variant)
        self.variant = self.desc.variant
        self.model = build_model(self.desc)
        self.data = self.model.createData()
        self.tool_id = self.model.getFrameId(self.desc.tool_frame)
        self.joint_names = list(self.desc.kinematic_joint_names)
        self.lower = np.asarray(self.desc.lower_limits(), dtype=float)
        self.upper = np.asarray(self.desc.upper_limits(), dtype=float)
        self.nq = self.model.nq
        self.root_frame = self.desc.root_frame
        # Revolute joints (wrapped to (-pi, pi]); the rail is prismatic.
        self.revolute = np.array([self.model.joints[i].shortname().startswith("JointModelR")
                                  for i in range(1, self.model.njoints)])
        # every joint is within its limits when |q_i| <= safe_range (fast path of checks)
        self.safe_range = float(max(0.0, min(np.min(-self.lower), np.min(self.upper))))
        self._reach_setup()

    # --- validation -------------------------------------------------------------------
    def _q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (self.nq,):
            raise InvalidSeedError(
                f"expected {self.nq} joint values ({', '.join(self.joint_names)}), "
                f"got {q.shape[0]}")
        if not np.all(np.isfinite(q)):
            bad = [n for n, v in zip(self.joint_names, q) if not math.isfinite(v)]
            raise InvalidSeedError(f"non-finite joint values for {', '.join(bad)}")
        return q

    # --- public, validated, copying API -------------------------------------------------
    def forward(self, q: np.ndarray) -> np.ndarray:
        """4x4 pose of tool0 in the root frame."""
        pin.forwardKinematics(self.model, self.data, self._q(q))
        return pin.updateFramePlacement(self.model, self.data, self.tool_id).homogeneous.copy()

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """6 x nq Jacobian of tool0, LOCAL_WORLD_ALIGNED (linear rows first)."""
        return pin.computeFrameJacobian(self.model, self.data, self._q(q), self.tool_id,
                                        _LWA).copy()

    # --- hot path (no validation, views) -----------------------------------------------
    def pose_view(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(position (3,), rotation (3,3)) of tool0 at q. Views: copy to keep."""
        pin.forwardKinematics(self.model, self.data, q)
        m = pin.updateFramePlacement(self.model, self.data, self.tool_id)
        return m.translation, m.rotation

    def pose_jacobian_view(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, rotation, 6 x nq Jacobian) of tool0 at q in one pinocchio pass."""
        j = pin.computeFrameJacobian(self.model, self.data, q, self.tool_id, _LWA)
        m = self.data.oMf[self.tool_id]
        return m.translation, m.rotation, j

    def joint_origins_view(self) -> list[np.ndarray]:
        """Origins of the joints (root frame) from the last kinematics call."""
        return [self.data.oMi[i].translation for i in range(1, self.model.njoints)]

    # --- limits --------------------------------------------------------------------------
    def clip(self, q: np.ndarray) -> np.ndarray:
        """q clipped into the joint limits (a new array)."""
        return np.minimum(np.maximum(q, self.lower), self.upper)

    def within_limits(self, q: np.ndarray) -> bool:
        return bool(np.all(q >= self.lower) and np.all(q <= self.upper))

    def limit_violations(self, q: np.ndarray) -> list[str]:
        """Names of the joints outside their limits at q."""
        bad = (q < self.lower) | (q > self.upper)
        return [n for n, b in zip(self.joint_names, bad) if b]

    def wrap(self, q: np.ndarray) -> np.ndarray:
        """Revolute joints wrapped into (-pi, pi] (same pose); the rail is untouched."""
        out = np.array(q, dtype=float)
        r = self.revolute
        out[r] = -((-out[r] + math.pi) % (2.0 * math.pi) - math.pi)
        return out

    def random_configuration(self, rng: np.random.Generator) -> np.ndarray:
        """Uniform random joints within the limits."""
        return rng.uniform(self.lower, self.upper)

    # --- reach ---------------------------------------------------------------------------
    def _reach_setup(self) -> None:
        """Upper bound of the distance from the first arm joint's origin to tool0.

        Every link is rigid, so |o_{i+1} - o_i| is constant; the triangle inequality bounds
        the tool's distance from joint1's origin by the sum of these lengths (m). For the
        rail variant joint1's origin moves along a segment (the rail's travel).
        """
        first_arm = 2 if self.variant == "rail_arm" else 1
        lengths = [np.linalg.norm(self.model.jointPlacements[i].translation)
                   for i in range(first_arm + 1, self.model.njoints)]
        lengths.append(np.linalg.norm(self.model.frames[self.tool_id].placement.translation))
        self.reach = float(sum(lengths))
        q = np.zeros(self.nq)
        pin.forwardKinematics(self.model, self.data, q)
        self.shoulder_origin = self.data.oMi[first_arm].translation.copy()
        self._shoulder_list = self.shoulder_origin.tolist()
        if self.variant == "rail_arm":
            q[0] = 1.0
            pin.forwardKinematics(self.model, self.data, q)
            self.rail_direction = self.data.oMi[first_arm].translation - self.shoulder_origin
            self._rail_range = (float(self.lower[0]), float(self.upper[0]))
        else:
            self.rail_direction = None

    def reach_excess(self, p: np.ndarray) -> float:
        """How far (m) ``p`` lies beyond the reach bound; > 0 means certainly unreachable."""
        if self.rail_direction is None:
            d = math.dist(p.tolist(), self._shoulder_list)
        else:
            u = self.rail_direction
            s = float(np.dot(p - self.shoulder_origin, u) / np.dot(u, u))
            s = min(max(s, self._rail_range[0]), self._rail_range[1])
            d = float(np.linalg.norm(p - self.shoulder_origin - s * u))
        return d - self.reach
