"""Core tests of the camera input: extrinsics, averaging, outliers, staleness (no rclpy)."""
from __future__ import annotations

import numpy as np
import pytest

from hyperarm_description import load_description
from hyperarm_tasks.perception import DetectionBuffer, camera_pose

pytestmark = pytest.mark.core


def _at(xyz):
    m = np.eye(4)
    m[:3, 3] = xyz
    return m


def test_camera_extrinsics_map_camera_link_to_the_root_frame():
    cam = camera_pose(load_description())
    # camera 0.6 m above the base, 0.3 m ahead, x (viewing direction) straight down
    assert cam[:3, 3] == pytest.approx([0.30, 0.0, 0.60])
    assert cam[:3, 0] == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
    buf = DetectionBuffer(cam)
    buf.add(10.0, ["peg"], [_at([0.72, 0.12, 0.05])])        # 0.72 m along the view axis
    est = buf.estimate("peg", now=10.1, n=1, max_age=1.0)
    assert est.xyz == pytest.approx(cam[:3, :3] @ [0.72, 0.12, 0.05] + cam[:3, 3])
    assert est.xyz[2] == pytest.approx(0.60 - 0.72)


def test_average_rejects_outliers_and_needs_enough_fresh_frames():
    buf = DetectionBuffer(np.eye(4))
    rng = np.random.default_rng(0)
    truth = np.array([0.35, -0.12, -0.12])
    for k in range(8):
        xyz = truth + rng.normal(0.0, 0.001, 3)
        if k == 5:
            xyz = truth + [0.05, 0.0, 0.0]                     # a wrong detection
        buf.add(1.0 + 0.1 * k, ["peg"], [_at(xyz)])
    est = buf.estimate("peg", now=1.75, n=5, max_age=1.0, outlier=0.01)
    assert est.used == 4 and est.rejected == 1
    assert np.linalg.norm(est.xyz - truth) < 0.002
    assert est.age == pytest.approx(0.05)
    assert buf.estimate("peg", now=1.75, n=9, max_age=1.0) is None          # too few
    assert buf.estimate("peg", now=3.0, n=5, max_age=1.0) is None           # stale
    assert buf.estimate("cup", now=1.75, n=1, max_age=1.0) is None          # never seen
    assert buf.newest("peg").stamp == pytest.approx(1.7)
