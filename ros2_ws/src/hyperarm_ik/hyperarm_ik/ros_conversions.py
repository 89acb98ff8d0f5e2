"""Conversions between geometry_msgs/sensor_msgs and numpy (imports message types, not
rclpy)."""
from __future__ import annotations

from typing import Iterable

import numpy as np
import pinocchio as pin
from geometry_msgs.msg import Pose
from sensor_msgs.msg import JointState

from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.log_throttle import ReasonThrottle

__all__ = ["matrix_to_pose", "pose_to_matrix", "joint_state", "JointStateInput"]


class JointStateInput:
    """joint_states as the force nodes read them: every message merged by name into
    ``cache`` (each driver publishes its own joints); a malformed one is dropped whole with
    a warning, throttled per reason through ``throttle``. ``logger``: anything with
    ``warn(str)`` (a node's logger)."""

    def __init__(self, logger, throttle: ReasonThrottle | None = None) -> None:
        self.cache = JointStateCache()
        self._logger = logger
        self._throttle = throttle if throttle is not None else ReasonThrottle(5.0)

    def merge(self, msg: JointState) -> bool:
        """Merge ``msg``; False (and a throttled warning) if it was malformed."""
        try:
            self.cache.update(msg.name, msg.position, msg.velocity, msg.effort)
        except JointStateError as exc:
            if (text := self._throttle.message(f"joint_states ignored: {exc}")):
                self._logger.warn(text)
            return False
        return True

    def ready(self, names: Iterable[str], with_effort: Iterable[str] = ()) -> bool:
        """Positions of every joint of ``names`` and efforts of ``with_effort`` seen."""
        return self.cache.has(names) and all(n in self.cache.effort for n in with_effort)


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
