"""Camera detections for tasks: camera_link -> root frame, averaging, staleness (no ROS).

The node feeds every Detections message (poses in ``camera_link``, stamp = exposure time)
into a :class:`DetectionBuffer`; it transforms them to the root frame with the camera's
extrinsics from the robot description (:func:`camera_pose`) and keeps the newest frames of
each object. :meth:`DetectionBuffer.estimate` averages the newest ``n`` frames not older
than ``max_age``, rejecting outliers (positions farther than ``outlier`` m from the median).
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from hyperarm_description.model import RobotDescription, camera_link_pose

__all__ = ["camera_pose", "Sighting", "Estimate", "DetectionBuffer", "DOWN", "quat_to_matrix",
           "matrix_to_quat"]

# tool0 orientation with the hand (along tool0's -y) pointing straight down: x along root x,
# y along root +z, z (the fingers' closing direction) along root -y.
DOWN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
DOWN.flags.writeable = False


def camera_pose(desc: RobotDescription) -> np.ndarray:
    """4x4 pose of camera_link in the root frame (description's xyz, rpy fixed axes):
    :func:`hyperarm_description.model.camera_link_pose`."""
    return camera_link_pose(desc)


def quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    q = np.array([x, y, z, w], dtype=float)
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError(f"bad quaternion {q.tolist()}")
    x, y, z, w = q / n
    return pin.Quaternion(w, x, y, z).toRotationMatrix()


def matrix_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    q = pin.Quaternion(np.asarray(r, dtype=float))
    return float(q.x), float(q.y), float(q.z), float(q.w)


@dataclass(frozen=True)
class Sighting:
    stamp: float          # s, exposure time (node clock)
    pose: np.ndarray      # 4x4 in the root frame


@dataclass(frozen=True)
class Estimate:
    """An averaged detection: ``pose`` (4x4, root frame; rotation of the newest inlier),
    ``used`` frames averaged, ``rejected`` outliers, ``age`` (s) of the newest, and
    ``stamp`` (s) the newest's exposure time."""

    pose: np.ndarray
    used: int
    rejected: int
    age: float
    stamp: float = float("nan")

    @property
    def xyz(self) -> np.ndarray:
        return self.pose[:3, 3]


class DetectionBuffer:
    """The newest ``history`` sightings of each object (thread-safe)."""

    def __init__(self, cam_in_root: np.ndarray, history: int = 30) -> None:
        self._cam = np.asarray(cam_in_root, dtype=float)
        self._lock = threading.Lock()
        self._history = history
        self._seen: dict[str, deque[Sighting]] = {}
        self.frames = 0
        #: s, exposure time of the newest frame that showed any object (-inf: none yet)
        self.last_seen_any = float("-inf")

    def add(self, stamp: float, names, poses_in_camera) -> None:
        """One Detections message: ``poses_in_camera`` are 4x4 in camera_link."""
        with self._lock:
            self.frames += 1
            if len(names):
                self.last_seen_any = max(self.last_seen_any, float(stamp))
            for name, pose in zip(names, poses_in_camera):
                q = self._seen.setdefault(name, deque(maxlen=self._history))
                q.append(Sighting(float(stamp), self._cam @ np.asarray(pose, dtype=float)))

    def newest(self, name: str) -> Sighting | None:
        with self._lock:
            q = self._seen.get(name)
            return q[-1] if q else None

    def since(self, name: str, stamp: float) -> list[Sighting]:
        """The kept sightings of ``name`` exposed after ``stamp`` (s), oldest first."""
        with self._lock:
            return [s for s in self._seen.get(name, ()) if s.stamp > stamp]

    def clear(self, name: str | None = None) -> None:
        with self._lock:
            if name is None:
                self._seen.clear()
            else:
                self._seen.pop(name, None)

    def estimate(self, name: str, now: float, n: int, max_age: float,
                 outlier: float = 0.01, since: float | None = None) -> Estimate | None:
        """Average of the newest ``n`` sightings at most ``max_age`` s old and, with
        ``since``, taken after that time (None if fewer)."""
        with self._lock:
            q = list(self._seen.get(name, ()))
        fresh = [s for s in q if now - s.stamp <= max_age
                 and (since is None or s.stamp > since)][-n:]
        if len(fresh) < n:
            return None
        xyz = np.array([s.pose[:3, 3] for s in fresh])
        med = np.median(xyz, axis=0)
        keep = np.linalg.norm(xyz - med, axis=1) <= outlier
        if not keep.any():
            return None
        out = fresh[max(i for i, k in enumerate(keep) if k)].pose.copy()
        out[:3, 3] = xyz[keep].mean(axis=0)
        return Estimate(out, int(keep.sum()), int((~keep).sum()), now - fresh[-1].stamp,
                        fresh[-1].stamp)
