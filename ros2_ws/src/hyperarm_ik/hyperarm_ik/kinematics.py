"""Forward kinematics and Jacobians of tool0 on the pinocchio model (no ROS).

Units: q in rad (rail in m), positions in m. Poses are 4x4 homogeneous matrices in the
model's root frame (base_link, or world for the rail variant). Jacobians are 6 x nq,
rows [v; w] in LOCAL_WORLD_ALIGNED (tool0 origin, root-frame axes).
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from hyperarm_description.model import RobotDescription, load_description
from hyperarm_description.pinocchio_model import build_model

__all__ = ["Kinematics"]


class Kinematics:
    """FK and Jacobian of ``tool0`` for one robot variant."""

    def __init__(self, desc: RobotDescription | None = None, variant: str = "arm") -> None:
        self.desc = desc if desc is not None else load_description(variant=variant)
        self.model = build_model(self.desc)
        self.data = self.model.createData()
        self.tool_id = self.model.getFrameId(self.desc.tool_frame)
        self.joint_names = self.desc.kinematic_joint_names
        self.lower = self.desc.lower_limits()
        self.upper = self.desc.upper_limits()
        self.nq = self.model.nq

    def _q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (self.nq,):
            raise ValueError(f"expected {self.nq} joint values ({', '.join(self.joint_names)}), "
                             f"got {q.shape[0]}")
        return q

    def forward(self, q: np.ndarray) -> np.ndarray:
        """4x4 pose of tool0 in the root frame."""
        pin.framesForwardKinematics(self.model, self.data, self._q(q))
        return self.data.oMf[self.tool_id].homogeneous.copy()

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """6 x nq Jacobian of tool0, LOCAL_WORLD_ALIGNED (linear rows first)."""
        return pin.computeFrameJacobian(self.model, self.data, self._q(q), self.tool_id,
                                        pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).copy()
