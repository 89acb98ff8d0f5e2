"""Core tier of hybrid_force's 'position' output pressing on the mock's simulation (issue 24
item 7, holding while pressing; no rclpy): the held block pressed on the destination peg's
top, 13 mm off its axis, z force-controlled, x and y held. ForceSimRobot runs the force
node's core in the loop, so the test lives here beside the other force simulations."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

pytestmark = [pytest.mark.core, pytest.mark.slow]

BLOCK = np.array([0.35, 0.12, -0.185])       # on the source peg (docs/mock.md)
PEG_TOP = -0.12 + 0.015                      # z of the block's bottom on the destination top
DEST = np.array([0.35, -0.12])
BASE_SIDE = (120, 180, 240)        # degrees around the destination peg, towards the base


def _press(kin, angle_deg: float, k: float, depth: float, seconds: float = 8.0):
    """Grasp the block, carry it over the destination peg at ``angle_deg`` around its axis
    (13 mm off), enable, and press with X0 ``depth`` m below the top at stiffness ``k``
    N/m. Returns (tool positions every 10 ms, X0, the contact force of the last 0.5 s,
    the robot)."""
    from hyperarm_driver.mock.config import default_workcell_path, load_mock_config
    from hyperarm_driver.mock.joint_sim import JointSim
    from hyperarm_driver.mock.scenario import Scenario
    from hyperarm_tasks.testing import ForceSimRobot

    cfg = load_mock_config(default_workcell_path())
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0, seed=1))
    sim = JointSim(kin.desc, cfg)
    sc = Scenario(sim, dt=0.01)
    sc.grip(1.2)
    sc.move_tool(BLOCK + [0.0, 0.0, 0.06], 3.0)
    sc.move_tool(BLOCK, 2.0)
    sc.grip(0.0, 0.6)
    for dz in (0.02, 0.04, 0.06, 0.08, 0.10):      # straight up off the peg
        sc.move_tool(BLOCK + [0.0, 0.0, dz], 1.0)
    a = math.radians(angle_deg)
    over = np.array([DEST[0] + 0.013 * math.cos(a), DEST[1] + 0.013 * math.sin(a),
                     PEG_TOP + 0.01])
    sc.move_tool(over, 3.0)
    robot = ForceSimRobot(sim, kin, params={"stale_timeout": 0.5})
    robot.sleep(1.0)
    assert robot.set_force_control(True) is None
    robot.sleep(1.0)
    idx = [sim.names.index(n) for n in robot.ctl.arm_names]
    x0 = over.copy()
    x0[2] = PEG_TOP - depth

    class Goal:
        xyz = x0
        rotation = kin.forward(sim.state().position[idx])[:3, :3]
        stiffness = [800.0, 800.0, k, 20.0, 20.0, 20.0]
        force_axes = (False, False, True, False, False, False)
        wrench = (0.0,) * 6

    robot.send_hybrid(Goal)
    xs, force = _record(robot, kin, seconds)
    return xs, x0, force, robot


def _record(robot, kin, seconds: float):
    """Tool positions every 10 ms for ``seconds``, and the contact force of the last 0.5 s."""
    sim = robot.sim
    idx = [sim.names.index(n) for n in robot.ctl.arm_names]
    xs, fs = [], []
    for _ in range(int(seconds / 0.01)):
        robot.sleep(0.01)
        xs.append(kin.forward(sim.state().position[idx])[:3, 3].copy())
        fs.append(sim.contact_wrench()[:3].copy())
    assert sim.world.state.name == "HELD" and robot.passive is None, robot.events
    return np.array(xs), np.array(fs[-50:]).mean(axis=0)


def test_x_and_y_hold_within_2_mm_through_the_whole_press(kin, k=1000.0, depth=0.010,
                                                         angles=(0, 60, 120, 180, 240, 300)):
    """About 9 N (1000 N/m, X0 10 mm below the top) from 6 directions around the peg:
    from contact to rest, x and y of the tool stay within 2 mm of X0 and the press settles
    at |K (X0 - X)| (10 % or 0.2 N). On the law before: 1.13-1.79 mm, and 6.6 N of 9.1 at
    180 degrees (the harder press below is the failing case)."""
    worst = 0.0
    for angle in angles:
        xs, x0, force, robot = _press(kin, angle, k, depth)
        xy = float(np.abs(xs[:, :2] - x0[:2]).max())
        worst = max(worst, xy)
        expected = abs(k * (x0[2] - xs[-50:, 2].mean()))
        print(f"K {k:g}, {angle} deg: x/y at most {xy * 1e3:.2f} mm off X0, press "
              f"{force[2]:.2f} N (expected {expected:.2f} N)")
        assert abs(force[2] - expected) <= max(0.1 * expected, 0.2), (angle, force, expected)
    assert worst < 0.002, f"x/y {worst * 1e3:.2f} mm off X0"


def test_a_hard_press_and_its_release_do_not_slip_sideways(kin):
    """28 N (4000 N/m, X0 8 mm below the top) then released to 1.5 N (200 N/m), from 6
    directions around the peg: x and y stay within 2 mm of X0 through the press and the
    release, and each settles at its goal's force. Fails on the law before: the press
    slid 2.4-2.7 mm (one max_speed budget for all the pseudo-goal's axes: a soft arm sends
    its pseudo-goal far along z to press, and the x/y correction was scaled down with it),
    and the release 26 mm (11-15 mm with the split budget but without force_rate: the
    servos kept pushing sideways against friction while the normal force fell). From the
    base's side of the peg (BASE_SIDE) the hard press is not checked for its force: there
    the mock's joint2 does not exert the push it is commanded (its measured effort -0.3 to
    -1.7 N·m against 6.1, the hand-written servo model's yield) and the press stays at
    2-12 N (docs/force.md); x/y and the release are checked there too."""
    worst = 0.0
    for angle in (0, 60, 120, 180, 240, 300):
        xs, x0, force, robot = _press(kin, angle, 4000.0, 0.008)
        pressed = float(np.abs(xs[:, :2] - x0[:2]).max())
        expected = min(abs(4000.0 * (x0[2] - xs[-50:, 2].mean())), 30.0)
        print(f"{angle} deg: pressed {force[2]:.2f} N (expected {expected:.2f} N), x/y at "
              f"most {pressed * 1e3:.2f} mm off X0")
        if angle not in BASE_SIDE:
            assert abs(force[2] - expected) <= max(0.1 * expected, 0.2), (angle, force,
                                                                           expected)
        worst = max(worst, pressed)

        class Release:
            xyz = x0
            rotation = robot.ctl.goal.rotation
            stiffness = [800.0, 800.0, 200.0, 20.0, 20.0, 20.0]
            force_axes = (False, False, True, False, False, False)
            wrench = (0.0,) * 6

        robot.send_hybrid(Release)
        xs, force = _record(robot, kin, 8.0)
        xy = float(np.abs(xs[:, :2] - x0[:2]).max())
        worst = max(worst, xy)
        expected = abs(200.0 * (x0[2] - xs[-50:, 2].mean()))
        print(f"{angle} deg: released to {force[2]:.2f} N (expected {expected:.2f} N), x/y at "
              f"most {xy * 1e3:.2f} mm off X0")
        assert abs(force[2] - expected) <= max(0.1 * expected, 0.2), (angle, force, expected)
    assert worst < 0.002, f"x/y {worst * 1e3:.2f} mm off X0 through a release"
