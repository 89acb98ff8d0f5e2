"""Core tests (issue 24, item 3) of the task node's input feeds: joint_states and detections
that are late, out of order, from the future or malformed are rejected whole, each kind
with its own reason (the log throttle's key) and a text naming the bad field; random
streams over several seeds."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_tasks.inputs import DetectionFeed, StateFeed

pytestmark = [pytest.mark.core]

NAMES = [f"joint{i}" for i in range(1, 10)]
UNIT = (0.0, 0.0, 0.0, 1.0)


def _state(feed, stamp, now, position=None, effort=None, names=NAMES):
    pos = [0.1] * len(names) if position is None else position
    return feed.check(names, pos, [0.0] * len(names),
                      [0.0] * len(names) if effort is None else effort, stamp, now)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_random_state_streams_use_only_new_fresh_messages(seed):
    """Messages arrive with random transport delays (some far longer than max_age) and so
    out of order; used: exactly those newer than every one used before and at most
    max_age old on arrival."""
    rng = np.random.default_rng(seed)
    feed = StateFeed(max_age=0.2)
    stamps = 100.0 + np.arange(400) * 0.01
    delays = np.where(rng.random(400) < 0.1, rng.uniform(0.25, 2.0, 400),
                      rng.exponential(0.02, 400))
    arrivals = sorted(zip(stamps + delays, stamps))
    newest, used = -math.inf, 0
    for now, stamp in arrivals:
        problem = _state(feed, stamp, now)
        expect = None if (now - stamp <= 0.2 and stamp >= newest) else (
            "joint_states stale" if now - stamp > 0.2 else "joint_states out_of_order")
        assert (problem and problem[0]) == expect, (now, stamp, problem)
        if problem is None:
            newest, used = stamp, used + 1
    counts = feed.counts()
    assert counts["joint_states_accepted"] == used
    assert counts["joint_states_rejected_stale"] + counts["joint_states_rejected_out_of_order"] \
        == 400 - used
    assert counts["joint_states_rejected_stale"] > 0 and \
        counts["joint_states_rejected_out_of_order"] > 0


def test_the_issues_late_message_is_rejected():
    """A joint_states stamped now - 2 s (3 cm off, say) in a 100 Hz stream is not used."""
    feed = StateFeed(max_age=0.5)
    for k in range(100):
        assert _state(feed, 10.0 + k * 0.01, 10.0 + k * 0.01 + 0.002) is None
    reason, text = _state(feed, 10.99 - 2.0, 11.0, position=[0.13] * 9)
    assert reason == "joint_states stale"
    assert "2.010 s ago" in text and "max_age 0.5 s" in text


def test_each_driver_is_its_own_source():
    """The arm's driver and the rail's publish their own joints with their own stamps: a
    rail message stamped just before the arm's newest is not out of order."""
    feed = StateFeed(max_age=0.5)
    assert _state(feed, 1.00, 1.01) is None
    assert _state(feed, 0.99, 1.01, names=["rail"]) is None
    assert _state(feed, 0.98, 1.02, names=["rail"])[0] == "joint_states out_of_order"


@pytest.mark.parametrize("bad, reason, field", [
    (dict(position=[0.1] * 8 + [float("nan")]), "joint_states position_nan", "joint9"),
    (dict(position=[float("inf")] + [0.1] * 8), "joint_states position_inf", "joint1"),
    (dict(effort=[0.0] * 4 + [float("nan")] + [0.0] * 4), "joint_states effort_nan",
     "effort of joint5"),
    (dict(effort=[0.0] * 8 + [-float("inf")]), "joint_states effort_inf", "effort of joint9"),
    (dict(position=[0.1] * 8), "joint_states length", "position has 8 values for 9 names"),
    (dict(names=NAMES[:8] + ["joint1"]), "joint_states duplicate", "joint1"),
])
def test_malformed_states_have_their_own_reason_and_name_the_field(bad, reason, field):
    feed = StateFeed(max_age=0.5)
    problem = _state(feed, 1.0, 1.0, **bad)
    assert problem is not None and problem[0] == reason
    assert field in problem[1]
    # a malformed message does not count as the newest used: a later good one is used
    assert _state(feed, 0.99, 1.0) is None


def _det(feed, stamp, now, frame="camera_link", names=("block",), poses=None):
    poses = [((0.35, 0.12, 0.5), UNIT)] * len(names) if poses is None else poses
    return feed.check(frame, list(names), poses, stamp, now)


@pytest.mark.parametrize("kwargs, reason, field", [
    (dict(frame="base_link"), "detections frame", "'base_link'"),
    (dict(names=("block", "source_peg"), poses=[((0.3, 0.1, 0.5), UNIT)]), "detections length",
     "2 names for 1 poses"),
    (dict(poses=[((0.3, float("nan"), 0.5), UNIT)]), "detections position_nan",
     "poses[0] ('block'): pose.position.y is NaN"),
    (dict(poses=[((0.3, 0.1, float("inf")), UNIT)]), "detections position_inf",
     "pose.position.z is inf"),
    (dict(poses=[((0.3, 0.1, 0.5), (0.0, float("nan"), 0.0, 1.0))]),
     "detections orientation_nan", "pose.orientation.y is NaN"),
    (dict(poses=[((0.3, 0.1, 0.5), (0.0, 0.0, 0.0, 0.0))]), "detections quaternion_norm",
     "not a unit quaternion"),
])
def test_malformed_detections_have_their_own_reason_and_name_the_field(kwargs, reason, field):
    feed = DetectionFeed("camera_link", max_age=1.0)
    problem = _det(feed, 1.0, 1.0, **kwargs)
    assert problem is not None and problem[0] == reason, problem
    assert field in problem[1], problem


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_random_detection_streams(seed):
    rng = np.random.default_rng(seed)
    feed = DetectionFeed("camera_link", max_age=1.0)
    stamps = 100.0 + np.arange(200) / 30.0
    delays = np.where(rng.random(200) < 0.1, rng.uniform(1.1, 3.0, 200),
                      rng.exponential(0.05, 200))
    newest = -math.inf
    for now, stamp in sorted(zip(stamps + delays, stamps)):
        problem = _det(feed, stamp, now)
        if now - stamp > 1.0:
            assert problem[0] == "detections stale"
        elif stamp < newest:
            assert problem[0] == "detections out_of_order"
        else:
            assert problem is None
            newest = stamp
    assert _det(feed, newest + 2.0, newest + 1.0)[0] == "detections future"


def test_three_kinds_in_a_row_are_three_log_lines():
    """The issue: 'three kinds in a row stay silent' under one throttle reason."""
    feed = DetectionFeed("camera_link", max_age=1.0)
    throttle = ReasonThrottle(5.0)
    shown = []
    for kwargs in (dict(poses=[((float("nan"), 0.0, 0.5), UNIT)]),
                   dict(poses=[((float("inf"), 0.0, 0.5), UNIT)]),
                   dict(poses=[((0.3, 0.0, 0.5), (0.0, 0.0, 0.0, 0.0))])):
        reason, text = _det(feed, 1.0, 1.0, **kwargs)
        if (m := throttle.message(text, reason)):
            shown.append(m)
    assert len(shown) == 3, shown
    assert feed.counts()["detections_rejected_position_nan"] == 1
    assert feed.counts()["detections_rejected_quaternion_norm"] == 1
