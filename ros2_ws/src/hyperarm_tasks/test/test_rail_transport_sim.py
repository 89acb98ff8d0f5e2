"""Core test of the shipped rail_transport (Jia et al.) on the mock's rail work cell, in the
mock's simulation (no rclpy, simulated time: ~4 s)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hyperarm_description import load_description
from hyperarm_driver.mock.config import default_workcell_path, load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_ik.kinematics import Kinematics
from hyperarm_tasks.runner import Runner
from hyperarm_tasks.sequence import load_task
from hyperarm_tasks.testing import SimRobot

pytestmark = [pytest.mark.core, pytest.mark.slow]


def test_rail_transport_carries_the_block_beyond_reach_and_returns():
    desc = load_description(variant="rail_arm")
    kin = Kinematics(desc)
    base = load_mock_config(default_workcell_path().with_name("workcell_rail.yaml"))
    cfg = dataclasses.replace(
        base, imperfections=dataclasses.replace(base.imperfections, seed=41),
        camera=dataclasses.replace(base.camera, seed=1041))
    sim = JointSim(desc, cfg)
    robot = SimRobot(sim)
    pegs = {p.name: np.array(p.xy) for p in cfg.world.spec.pegs}
    rails = []
    real = robot.command
    robot.command = lambda pos, eff=None: (rails.append(pos["rail"]) if "rail" in pos else None,
                                           real(pos, eff))
    result = Runner(robot, kin, load_task("rail_transport", desc)).run()
    assert result.success, result.message
    assert sim.world.on_peg("destination")
    assert sim.homed
    # from the start position (rail 0, the base at the origin) both pegs are more than 0.5 m
    # beyond the arm's reach bound, in x-y alone: the IK drove the rail along, to both ends,
    # and the task brought it back
    assert min(np.linalg.norm(p) for p in pegs.values()) > kin.reach + 0.5
    assert min(rails) < pegs["source"][0] + 0.6 and max(rails) > pegs["destination"][0] - 0.6
    assert sim.position[0] == pytest.approx(0.0, abs=0.002)
    assert result.step_names[-1] == "return" and result.metrics["insertion_depth"] >= 0.005
