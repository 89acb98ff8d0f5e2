"""Core tests of joint-state merging and command validation (no rclpy)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_description.joints import JointStateCache, JointStateError, check_command

pytestmark = pytest.mark.core


def test_cache_merges_by_name_from_several_drivers():
    cache = JointStateCache()
    cache.update(["joint1", "joint2"], [0.1, 0.2], [1.0, 2.0], [], stamp=1.0)
    cache.update(["rail"], [0.5], stamp=2.0)
    cache.update(["joint1"], [0.3], stamp=3.0)
    assert cache.positions(["rail", "joint1", "joint2"]) == pytest.approx([0.5, 0.3, 0.2])
    assert cache.velocity == {"joint1": 1.0, "joint2": 2.0}
    assert cache.has(["joint1", "rail"]) and not cache.has(["joint9"])


def test_cache_names_missing_joints_and_bad_lengths():
    cache = JointStateCache()
    cache.update(["joint1"], [0.0])
    with pytest.raises(JointStateError, match="joint2, joint3"):
        cache.positions(["joint1", "joint2", "joint3"])
    with pytest.raises(JointStateError, match="position has 1 values for 2 names"):
        cache.update(["a", "b"], [1.0])


def test_check_command_accepts_valid():
    out = check_command(["joint2", "gripper"], np.array([0.5, 0.1]), ["joint1", "joint2", "gripper"])
    assert out == {"joint2": 0.5, "gripper": 0.1}


@pytest.mark.parametrize("names,values,msg", [
    (["joint1"], [0.1, 0.2], "2 values for 1 joint names"),
    (["joint1", "joint1"], [0.1, 0.2], "duplicate joint names"),
    (["joint1", "elbow"], [0.1, 0.2], r"unknown joint\(s\) \['elbow'\]"),
    (["joint1"], [math.nan], r"non-finite position for \['joint1'\]"),
    (["joint1"], [math.inf], "non-finite"),
])
def test_check_command_rejects(names, values, msg):
    with pytest.raises(JointStateError, match=msg):
        check_command(names, values, ["joint1", "joint2"])


def test_velocity_problem_judges_the_whole_message():
    from hyperarm_description.joints import velocity_problem

    assert velocity_problem(["joint1"], []) is None                 # no velocities: fine
    assert velocity_problem(["joint1", "rail"], [0.0, 1.5]) is None
    assert "3 values for 1" in velocity_problem(["joint1"], [0.0, 0.0, 0.0])
    assert "rail" in velocity_problem(["joint1", "rail"], [0.0, float("nan")])
    assert "joint1" in velocity_problem(["joint1"], [float("inf")])
