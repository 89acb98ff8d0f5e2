"""Conversions between geometry_msgs and numpy (imports message types, not rclpy)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
from geometry_msgs.msg import Pose
from sensor_msgs.msg import JointState

__all__ = ["matrix_to_pose", "pose_to_matrix", "joint_state"]


def matrix_to_pose(t: np.ndarray) -> Pose:
    """4x4 homogeneous matrix (m) -> geometry_msgs/Pose (unit quaternion)."""
    q = pin.Quaternion(np.asarray(t[:3, :3], dtype=float))
    q.normalize()
    out = Pose()
    out.position.x, out.position.y, out.position.z = (float(v) for v in t[:3, 3])
    out.orientation.x, out.orientation.y = float(q.x), float(q.y)
    out.orientation.z, out.orientation.w = float(q.z), float(q.w)
    return out


def pose_to_matrix(p: Pose) -> np.ndarray:
    """geometry_msgs/Pose -> 4x4 matrix. The quaternion must be normalised by the caller."""
    q = pin.Quaternion(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z)
    t = np.eye(4)
    t[:3, :3] = q.toRotationMatrix()
    t[:3, 3] = (p.position.x, p.position.y, p.position.z)
    return t


def joint_state(names, positions) -> JointState:
    """sensor_msgs/JointState with ``names`` and ``positions`` (rad, rail m); no stamp."""
    out = JointState()
    out.name = list(names)
    out.position = [float(v) for v in positions]
    return out
