"""A simulated fixed camera that detects objects with noise and latency (no ROS).

Poses are 4x4 homogeneous matrices; ``truth`` is given in the robot's root frame and the
detections are expressed in ``camera_link`` (position noise in m per camera axis,
orientation noise as a small rotation, rad per axis). An image is taken every 1/rate s of
simulated time; its detections become available ``latency`` s later and carry the exposure
time as their stamp.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
import pinocchio as pin

from .config import CameraConfig

__all__ = ["Frame", "Camera", "pose_from_xyz_rpy"]


def pose_from_xyz_rpy(xyz, rpy) -> np.ndarray:
    """4x4 pose from a translation (m) and roll-pitch-yaw (rad, fixed axes x, y, z)."""
    out = np.eye(4)
    out[:3, :3] = pin.rpy.rpyToMatrix(*[float(a) for a in rpy])
    out[:3, 3] = xyz
    return out


@dataclass(frozen=True)
class Frame:
    """One image's detections: ``stamp`` = exposure time (s); poses in camera_link.
    ``dropped``: taken during a configured camera dropout: nothing detected (the truth is
    still there, for tests)."""

    stamp: float
    names: tuple[str, ...]
    detected: tuple[np.ndarray, ...]
    truth: tuple[np.ndarray, ...]
    dropped: bool = False


class Camera:
    """A camera at ``pose`` (camera_link in the root frame) taking images of the work cell."""

    def __init__(self, cfg: CameraConfig, pose: np.ndarray) -> None:
        self.cfg = cfg
        self.pose = np.asarray(pose, dtype=float)
        self._inv = np.linalg.inv(self.pose)
        self._rng = np.random.default_rng(cfg.seed)
        self._period = 1.0 / cfg.rate
        self._next: float | None = None
        self._pending: deque[tuple[float, Frame]] = deque()

    def capture(self, stamp: float, truth: Mapping[str, np.ndarray]) -> Frame:
        """Take one image now: true and noisy poses of ``truth`` in camera_link."""
        names, det, tru = [], [], []
        for name, world_pose in truth.items():
            t = self._inv @ world_pose
            n = t.copy()
            if self.cfg.position_noise > 0.0:
                n[:3, 3] += self._rng.normal(0.0, self.cfg.position_noise, 3)
            if self.cfg.orientation_noise > 0.0:
                turn = self._rng.normal(0.0, self.cfg.orientation_noise, 3)
                n[:3, :3] = t[:3, :3] @ pin.exp3(turn)
            names.append(name)
            det.append(n)
            tru.append(t)
        return Frame(stamp, tuple(names), tuple(det), tuple(tru),
                     dropped=self.cfg.dropped(stamp))

    def step(self, now: float, truth: Callable[[], Mapping[str, np.ndarray]]) -> list[Frame]:
        """Advance to ``now`` (s): take an image if one is due (``truth()`` is called only
        then) and return the frames whose latency has elapsed, oldest first."""
        if self._next is None:
            self._next = now
        if now >= self._next:
            self._pending.append((now + self.cfg.latency, self.capture(now, truth())))
            self._next += self._period
            if self._next <= now:  # fell behind (e.g. paused): do not burst
                self._next = now + self._period
        out = []
        while self._pending and self._pending[0][0] <= now + 1e-12:
            out.append(self._pending.popleft()[1])
        return out
