"""Core tier: the simulated camera (frame transform, noise statistics, rate, latency)."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.model import load_description
from hyperarm_driver.mock.camera import Camera, pose_from_xyz_rpy
from hyperarm_driver.mock.config import CameraConfig, load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim

pytestmark = pytest.mark.core


@pytest.fixture(scope="module")
def desc():
    return load_description()


def camera(desc, **kw) -> Camera:
    return Camera(CameraConfig(**kw), pose_from_xyz_rpy(desc.camera.xyz, desc.camera.rpy))


def test_truth_is_expressed_in_camera_link(desc):
    """camera_link sits 0.6 m above the base looking straight down (x along -z)."""
    sim = JointSim(desc, load_mock_config())
    frame = camera(desc).capture(0.0, sim.truth())
    assert frame.names == ("block", "source_peg", "destination_peg")
    cam = np.array(desc.camera.xyz)
    peg = sim.world.peg_top("destination")[:3, 3]
    # x of camera_link points down (root -z); its origin is at the camera.
    dest = frame.truth[2]
    assert dest[0, 3] == pytest.approx(cam[2] - peg[2])
    assert np.linalg.norm(dest[:3, 3]) == pytest.approx(np.linalg.norm(peg - cam))
    # the same as pinocchio's own camera_link frame of the robot model
    data = sim.model.createData()
    pin.framesForwardKinematics(sim.model, data, np.zeros(9))
    cam_model = data.oMf[sim.model.getFrameId(desc.camera.frame)].homogeneous
    assert dest == pytest.approx(np.linalg.inv(cam_model) @ sim.world.peg_top("destination"))
    assert frame.detected[2] == pytest.approx(dest)          # noiseless by default


def test_noise_statistics_match_the_configuration(desc):
    sp, so = 0.002, 0.01
    cam = camera(desc, position_noise=sp, orientation_noise=so, seed=7)
    truth = {"block": pose_from_xyz_rpy([0.35, 0.12, -0.185], [0.0, 0.0, 0.3])}
    n = 3000
    dp, dr = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        f = cam.capture(0.0, truth)
        dp[i] = f.detected[0][:3, 3] - f.truth[0][:3, 3]
        dr[i] = pin.log3(f.truth[0][:3, :3].T @ f.detected[0][:3, :3])
    # standard deviation per axis within 10 % (the estimate's own spread is ~1.3 %)
    assert dp.std(axis=0) == pytest.approx([sp] * 3, rel=0.1)
    assert dr.std(axis=0) == pytest.approx([so] * 3, rel=0.1)
    # unbiased: means within 4 standard errors
    assert np.all(np.abs(dp.mean(axis=0)) < 4 * sp / math.sqrt(n))
    assert np.all(np.abs(dr.mean(axis=0)) < 4 * so / math.sqrt(n))
    # independent axes
    assert abs(np.corrcoef(dp[:, 0], dp[:, 1])[0, 1]) < 0.1


def test_rate_and_latency(desc):
    cam = camera(desc, rate=10.0, latency=0.1)
    dt = 0.005
    got = []
    for k in range(1, 1001):                    # 5 s of simulated time
        now = k * dt
        for frame in cam.step(now, lambda: {"x": np.eye(4)}):
            got.append((now, frame.stamp))
    assert len(got) in (49, 50)                 # 10 Hz over 5 s, minus the last in flight
    stamps = np.array([s for _, s in got])
    assert np.diff(stamps) == pytest.approx(0.1, abs=dt + 1e-9)
    delays = np.array([now - s for now, s in got])
    assert delays == pytest.approx(0.1, abs=dt + 1e-9)   # published 100 ms after exposure
