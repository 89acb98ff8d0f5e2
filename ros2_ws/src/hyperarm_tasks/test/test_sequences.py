"""Core tests of task sequences (no rclpy)."""
from __future__ import annotations

import math

import pytest

from hyperarm_description import load_description
from hyperarm_tasks.sequences import (TASKS, Stage, StageStatus, UnknownTaskError, build_task,
                                      stage_status)

pytestmark = pytest.mark.core


@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
@pytest.mark.parametrize("task", sorted(TASKS))
def test_every_task_goal_is_known_and_within_limits(task, variant):
    desc = load_description(variant=variant)
    limits = desc.limits_by_name()
    stages = build_task(task, desc)
    assert stages
    for stage in stages:
        for name, goal in stage.goal.items():
            lo, hi = limits[name]
            assert lo <= goal <= hi, (task, stage.name, name)


def test_ready_ends_at_q_zero_with_gripper_open():
    desc = load_description()
    stages = build_task("ready", desc)
    assert stages[0].goal == {"gripper": desc.gripper.upper}
    assert stages[-1].goal == {f"joint{i}": 0.0 for i in range(1, 10)}


def test_unknown_task_lists_known_ones():
    with pytest.raises(UnknownTaskError, match=r"unknown task 'dance'; known tasks: ready, rest"):
        build_task("dance", load_description())


def test_stage_status():
    stage = Stage("s", {"a": 1.0, "b": -1.0}, tolerance=0.01, timeout=2.0)
    assert stage_status(stage, {"a": 1.0}, 0.5) is StageStatus.RUNNING  # b unknown
    assert stage_status(stage, {"a": 1.0, "b": -0.98}, 0.5) is StageStatus.RUNNING
    assert stage_status(stage, {"a": 1.005, "b": -0.995}, 0.5) is StageStatus.DONE
    assert stage_status(stage, {"a": 0.0, "b": -1.0}, 2.5) is StageStatus.TIMED_OUT


@pytest.mark.parametrize("kwargs,msg", [
    (dict(goal={}), "empty goal"), (dict(goal={"a": 0}, tolerance=0.0), "tolerance"),
    (dict(goal={"a": 0}, timeout=math.nan), "timeout"),
])
def test_stage_validation(kwargs, msg):
    with pytest.raises(ValueError, match=msg):
        Stage("s", **kwargs)
