"""The calibration's postures (core tier: pinocchio, coal, no rclpy): every posture keeps every
rule, whatever the seed; consecutive ones are joined by collision-free joint paths; the set
is diverse enough for the hand-eye solution; impossible rules and bad poses are refused."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hyperarm_description.mjcf import camera_link_pose
from hyperarm_description.model import load_description, read_yaml
from hyperarm_description.world import MOCK_WORLD_KEYS, parse_world
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics
from hyperarm_perception.calibration_postures import (NOMINAL_TARGET, PostureError,
                                                      PostureRules, parse_pose,
                                                      target_postures)
from hyperarm_perception.handeye import check_pose_diversity
from hyperarm_perception.markers import T_LINK_OPTICAL, CameraModel, PerceptionError

pytestmark = pytest.mark.core

CELL = Path(__file__).resolve().parents[2] / "hyperarm_driver" / "config" / "workcell.yaml"


@pytest.fixture(scope="module")
def setup():
    desc = load_description(None, "arm")
    world = parse_world(read_yaml(CELL, "work cell")["world"], extra_keys=MOCK_WORLD_KEYS)
    kin = Kinematics(desc)
    return desc, world, kin, CollisionModel(kin, world)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_posture_keeps_every_rule(setup, seed):
    desc, world, kin, col = setup
    cam = CameraModel.from_fovy(640, 480, desc.camera.fovy)
    X = camera_link_pose(desc)
    Y = parse_pose(NOMINAL_TARGET, "target")
    rules = PostureRules()
    start = np.zeros(9)
    qs = target_postures(kin, col, cam, X, Y, 8, start, np.random.default_rng(seed),
                         rules, table_height=world.table.height)
    assert len(qs) == 8
    here = start
    for q in qs:
        assert kin.within_limits(q) and not col.in_collision(q)
        assert col.check_path(here, q).free
        here = q
        T = np.linalg.inv(X) @ kin.forward(q) @ Y            # the target in camera_link
        assert (kin.forward(q) @ Y)[2, 3] >= world.table.height + rules.clearance
        assert T[0, 3] >= rules.min_depth
        sight = T[:3, 3] / np.linalg.norm(T[:3, 3])
        assert -T[:3, 2] @ sight >= math.cos(rules.max_view_angle) - 1e-12
        o = T_LINK_OPTICAL.T @ T[:, 3]
        u, v = (cam.K @ o[:3])[:2] / o[2]
        assert rules.margin_px < u < 640 - rules.margin_px
        assert rules.margin_px < v < 480 - rules.margin_px
    diversity = check_pose_diversity([kin.forward(q) for q in qs])
    assert diversity.motions >= 3, diversity


def test_rules_nothing_can_keep_are_refused_saying_so(setup):
    desc, world, kin, col = setup
    cam = CameraModel.from_fovy(640, 480, desc.camera.fovy)
    with pytest.raises(PostureError, match="show the target to the camera"):
        target_postures(kin, col, cam, camera_link_pose(desc), parse_pose(NOMINAL_TARGET, "t"),
                        4, np.zeros(9), np.random.default_rng(0),
                        PostureRules(min_depth=5.0, max_draws=2000),
                        table_height=world.table.height)


@pytest.mark.parametrize("text", ["", "1 2 3", "1 2 3 4 5 6 7", "a b c d e f",
                                  "0 0 0 0 0 nan"])
def test_bad_poses_are_refused(text):
    with pytest.raises(PerceptionError, match="6 finite numbers"):
        parse_pose(text, "target")


def test_a_pose_from_text():
    T = parse_pose("0.1, 0.2 0.3 0 0 1.5707963267948966", "t")
    assert np.allclose(T[:3, 3], [0.1, 0.2, 0.3])
    assert np.allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
