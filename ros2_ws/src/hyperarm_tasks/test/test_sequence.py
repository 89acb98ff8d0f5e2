"""Core tests of task files: the shipped tasks load, bad files are rejected with file:line."""
from __future__ import annotations

import textwrap

import numpy as np
import pytest

from hyperarm_description import load_description
from hyperarm_tasks.errors import TaskFileError, UnknownTaskError
from hyperarm_tasks.sequence import load_task, load_task_file, task_names
from hyperarm_tasks.steps import STEP_TYPES

pytestmark = pytest.mark.core


@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
@pytest.mark.parametrize("task", ["ready", "rest", "block_transfer", "figure8"])
def test_shipped_tasks_load_and_stay_within_limits(task, variant):
    desc = load_description(variant=variant)
    limits = desc.limits_by_name()
    t = load_task(task, desc)
    assert t.steps
    for step in t.steps:
        for name, goal in getattr(step, "goal", {}).items():
            lo, hi = limits[name]
            assert lo <= goal <= hi, (task, step.name, name)
    if task == "ready":
        assert [s.name for s in t.steps][-1] == ("rail_centre" if variant == "rail_arm"
                                                 else "ready_pose")


def test_block_transfer_follows_the_papers_twelve_steps(desc):
    """The paper's twelve steps, and a locate after the first (the camera sees the block
    and the pegs before the hand is over them)."""
    t = load_task("block_transfer", desc)
    assert [s.type for s in t.steps] == [
        "move_joints", "locate", "move_to", "gripper", "move_to", "gripper", "move_to",
        "move_to", "force_insert", "move_to", "gripper", "retreat", "move_joints"]
    assert t.steps[1].objects == ("block", "source_peg", "destination_peg")
    insert = t.steps[8]
    assert insert.depth == pytest.approx(0.005) and insert.radius == pytest.approx(0.015)
    assert insert.retry.attempts == 1 and insert.retry.on == ("insertion",)
    assert t.steps[insert.retry.from_index].name == "above_destination"
    close = t.steps[5]
    assert close.effort == pytest.approx(0.6) and close.expect == "grasp"
    assert t.steps[close.retry.from_index].name == "ready"


def test_every_step_type_is_registered():
    assert sorted(STEP_TYPES) == ["force_insert", "gripper", "home_rail", "locate",
                                  "move_joints", "move_to", "retreat", "track_path", "wait_for"]


def test_figure8_is_the_benchmarks_and_rail_transport_needs_the_rail(desc):
    from hyperarm_ik.benchmark.ik_benchmark import figure8_targets
    from hyperarm_ik.kinematics import Kinematics
    from hyperarm_ik.paths import FIGURE8, hold_orientation
    track = load_task("figure8", desc).steps[-1]
    assert track.type == "track_path" and track.figure == FIGURE8
    assert track.waypoints == 1000 and track.reach == pytest.approx(0.001)
    assert track.min_reached == pytest.approx(0.999)
    kin = Kinematics(desc)
    bench = figure8_targets(kin, track.waypoints)          # the IK benchmark's set
    assert np.array_equal(np.array([p for p, _ in bench]), track.figure.points(1000))
    assert np.array_equal(bench[0][1], hold_orientation(kin))
    rail = load_task("rail_transport", load_description(variant="rail_arm"))
    assert [s.type for s in rail.steps] == [
        "home_rail", "move_joints", "move_to", "gripper", "move_to", "gripper", "move_to",
        "move_to", "force_insert", "move_to", "gripper", "retreat", "move_joints"]
    assert rail.steps[1].goal["rail"] == 0.0 and rail.steps[-1].goal["rail"] == 0.0
    with pytest.raises(TaskFileError, match=r"rail_transport.yaml:\d+: steps\[1\] \(ready\)"
                                            r".joints.rail: unknown joint 'rail'"):
        load_task("rail_transport", desc)                  # the fixed arm has no rail


def test_unknown_task_lists_known_ones(desc, tmp_path):
    with pytest.raises(UnknownTaskError, match=r"unknown task 'dance'; known tasks: "
                                                r"block_transfer, block_transfer_back, figure8, "
                                                r"rail_transport, ready, rest"):
        load_task("dance", desc)
    (tmp_path / "wave.yaml").write_text(
        "schema_version: 1\nsteps:\n  - {name: a, type: move_joints, arm: 0}\n")
    assert "wave" in task_names([tmp_path])
    assert load_task("wave", desc, [tmp_path]).steps[0].goal["joint9"] == 0.0


HEADER = "schema_version: 1\nobjects: [block]\nsteps:\n"


@pytest.mark.parametrize("body,line,reason", [
    ("  - {name: a, type: move_too}\n", 4, "unknown step type 'move_too'; known: force_insert"),
    ("  - {name: a, type: gripper}\n", 4, "'action' is missing"),
    ("  - name: a\n    type: gripper\n    action: open\n    colour: red\n", 7,
     "unknown field 'colour'"),
    ("  - name: a\n    type: move_to\n    target: {relative_to: block}\n    speed: 5 kg\n", 7,
     "bad unit 'kg' for a speed"),
    ("  - name: a\n    type: move_to\n    target: {relative_to: cup}\n", 6,
     "unknown object or frame 'cup'"),
    ("  - name: a\n    type: move_joints\n    joints: {joint3: 200 deg}\n", 6,
     "outside its limits"),
    ("  - name: a\n    type: move_joints\n    joints: {joint42: 0}\n", 6, "unknown joint"),
    ("  - name: a\n    type: retreat\n    distance: 2 cm/s\n", 6, "bad unit 'cm/s' for a length"
     " (that is a speed unit)"),
    ("  - {name: a, type: retreat, distance: 1 cm}\n  - {name: a, type: retreat, distance: 1 cm}\n",
     5, "duplicate step name"),
    ("  - {name: a, type: retreat, distance: 1 cm, retry: {attempts: 1, from: b}}\n"
     "  - {name: b, type: retreat, distance: 1 cm}\n", 4, "not this step or an earlier one"),
    ("  - {name: a, type: gripper, action: open\n", 5, "YAML syntax"),
    ("  - {name: a, type: track_path, path: circle}\n", 4, "'circle' is not one of figure8"),
    ("  - name: a\n    type: track_path\n    path: figure8\n    speed: 5 cm\n", 7,
     "bad unit 'cm' for a speed (that is a length unit)"),
    ("  - name: a\n    type: track_path\n    path: figure8\n    min_reached: 99.9\n", 7,
     "99.9 is greater than the maximum of 1"),
    ("  - name: a\n    type: track_path\n    path: figure8\n    acceleration: 1 m/s\n", 7,
     "bad unit 'm/s' for a acceleration"),
    ("  - name: a\n    type: track_path\n    path: figure8\n    center: [0.4, 0]\n", 7,
     "is too short"),
    ("  - {name: a, type: track_path}\n", 4, "'path' is missing"),
    ("  - name: a\n    type: force_insert\n    target: {relative_to: block}\n"
     "    force: 1 N\n    stiffness: 1000 N/m\n", 7,
     "force / stiffness (1.0 mm) must exceed contact_threshold (1.5 mm)"),
])
def test_bad_files_are_rejected_with_their_line(tmp_path, desc, body, line, reason):
    path = tmp_path / "bad.yaml"
    path.write_text(HEADER + body)
    with pytest.raises(TaskFileError) as info:
        load_task_file(path, desc)
    assert info.value.file == "bad.yaml"
    assert info.value.line == line, str(info.value)
    assert reason in info.value.reason, str(info.value)
    assert str(info.value).startswith(f"bad.yaml:{line}: ")


def test_missing_version_and_empty_file(tmp_path, desc):
    p = tmp_path / "t.yaml"
    p.write_text("steps: []\n")
    with pytest.raises(TaskFileError, match="schema_version"):
        load_task_file(p, desc)
    p.write_text("")
    with pytest.raises(TaskFileError, match="empty file"):
        load_task_file(p, desc)
    p.write_text(textwrap.dedent("""\
        schema_version: 2
        steps: [{name: a, type: retreat, distance: 1 cm}]
    """))
    with pytest.raises(TaskFileError, match=r"t.yaml:1: schema_version 2 is not supported"):
        load_task_file(p, desc)
