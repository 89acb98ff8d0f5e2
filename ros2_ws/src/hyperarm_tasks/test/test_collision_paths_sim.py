"""Core tests: the task runner's path collision check (hyperarm_ik's collision model), on the
mock's simulation of the pole work cell (no rclpy).

A straight tool line through the pole is refused before anything is sent, with the failure
kind ``collision`` and the colliding pair named; the same line with the check off is driven
into the pole (the mock's contact), which is what the check is for; a line clear of the pole
passes the check and runs.
"""
from __future__ import annotations

import textwrap

import numpy as np
import pytest

from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_tasks.runner import Runner
from hyperarm_tasks.sequence import load_task
from hyperarm_tasks.testing import SimRobot

pytestmark = [pytest.mark.core]

POLE_CELL = "workcell_pole.yaml"
START = np.array([0.35, -0.12])     # m, over the destination peg


def _pole_cfg(seed: int | None = None):
    """The shipped pole cell; its repeatability offsets from ``seed`` (the cell's is null: a
    random one)."""
    import dataclasses

    from hyperarm_driver.mock.config import default_workcell_path
    cfg = load_mock_config(default_workcell_path().parent / POLE_CELL)
    return dataclasses.replace(cfg, imperfections=dataclasses.replace(cfg.imperfections,
                                                                      seed=seed))


def _task(tmp_path, desc, to_xy):
    """Ready, then tool0 at 8.5 cm under the base, from over the destination peg to ``to_xy`` (the
    move from the stretched, singular ready pose falls back to joint space, as in
    block_transfer; the move across may not)."""
    (tmp_path / "through.yaml").write_text(textwrap.dedent(f"""\
        schema_version: 1
        description: a straight tool line between two points of the pole cell
        frames:
          start: {{xyz: [0.35, -0.12, -0.085]}}
          end: {{xyz: [{to_xy[0]}, {to_xy[1]}, -0.085]}}
        steps:
          - {{name: ready, type: move_joints, arm: 0}}
          - {{name: to_start, type: move_to, target: {{relative_to: start}}, speed: 20 cm/s}}
          - {{name: across, type: move_to, target: {{relative_to: end}}, speed: 20 cm/s,
             joint_fallback: false, timeout: 10 s}}
        """))
    return load_task("through", desc, [tmp_path])


def _run(desc, kin, task, check: bool, seed: int | None = None):
    from hyperarm_ik.collision import CollisionModel
    cfg = _pole_cfg(seed)
    sim = JointSim(desc, cfg)
    robot = SimRobot(sim)
    model = CollisionModel(kin, cfg.world.spec) if check else None
    runner = Runner(robot, kin, task, collisions=model)
    sent: dict[str, int] = {}

    real = robot.command

    def counted(positions, efforts=None):
        if runner.step is not None:
            sent[runner.step.name] = sent.get(runner.step.name, 0) + 1
        return real(positions, efforts)

    robot.command = counted
    return runner.run(), sim, sent


def test_a_line_through_the_pole_is_refused_before_anything_is_sent(desc, kin, tmp_path):
    pole = _pole_cfg().world.spec.poles[0]
    # from over the destination peg (0.35, -0.12) through the pole's axis, and beyond it
    end = START + 1.45 * (np.asarray(pole.xy) - START)
    task = _task(tmp_path, desc, end)
    result, sim, sent = _run(desc, kin, task, check=True)
    assert not result.success
    assert result.failure_kind == "collision", result.message
    assert "across" in result.message and "pole" in result.message, result.message
    assert "across" not in sent, "a command of the refused step reached the robot"
    assert sent.get("to_start", 0) > 0               # the step before it did run


@pytest.mark.parametrize("seed", [9, 11, 18])
def test_without_the_check_the_same_line_drives_into_the_pole(desc, kin, tmp_path, seed):
    """Seeds 9, 11 and 18 are offsets with which the mock once let the arm through the pole
    (the task then succeeded): a new move's offset drawn while a link pressed the pole."""
    pole = _pole_cfg().world.spec.poles[0]
    end = START + 1.45 * (np.asarray(pole.xy) - START)
    task = _task(tmp_path, desc, end)
    result, sim, sent = _run(desc, kin, task, check=False, seed=seed)
    assert sent.get("across", 0) > 0
    # the mock's pole stops the arm: a servo overloads (hardware error), or the tool ends
    # short of the far end
    assert not result.success
    assert result.failure_kind in ("driver", "timeout"), result.message
    assert "across" in result.message, result.message


def test_a_line_clear_of_the_pole_passes_the_check_and_runs(desc, kin, tmp_path):
    task = _task(tmp_path, desc, (0.35, 0.12))        # over to the source peg
    result, sim, sent = _run(desc, kin, task, check=True)
    assert result.success, result.message
    assert sent.get("across", 0) > 0
