"""Core tier: the simulated servos (tracking, limits, bad input, watchdog, torque mode against
gravity, torque off, reboot, latency, noise, rail homing). No ROS."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.joints import JointStateError
from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import (OVERLOAD_TIME, ControlMode, JointSim,
                                            MockCommandError)

pytestmark = pytest.mark.core

DT = 0.005
ARM = [f"joint{i}" for i in range(1, 10)]


def config(current: bool = False, **imperfections):
    """The packaged cell without repeatability; ideal servos (no current model, no torque
    gap at a mode switch) unless ``current``: those have their own tests
    (test_mock_servo.py)."""
    cfg = load_mock_config()
    imp = dataclasses.replace(cfg.imperfections, repeatability=0.0, seed=1, **imperfections)
    return dataclasses.replace(
        cfg, imperfections=imp, current=dataclasses.replace(cfg.current, enabled=current),
        servo=dataclasses.replace(cfg.servo, mode_switch_gap=cfg.servo.mode_switch_gap
                                  if current else 0.0))


@pytest.fixture(scope="module")
def desc():
    return load_description()


@pytest.fixture
def sim(desc):
    return JointSim(desc, config())


def run(sim, seconds, record=None):
    for _ in range(int(round(seconds / DT))):
        sim.step(DT)
        if record is not None:
            record.append((sim.time, sim.position.copy(), sim.velocity.copy()))


def test_profile_acceleration_0_is_velocity_limited_only(desc):
    """A servo's Profile Acceleration 0 (unlimited): the profile moves at the velocity limit
    from the first step, straight to the goal, without overshoot."""
    j = desc.joints[0]
    cfg = config()
    sim = JointSim(desc, dataclasses.replace(
        cfg, servo=dataclasses.replace(cfg.servo, profile_acceleration=0.0)))
    sim.command(["joint1"], [1.0])
    trace: list = []
    run(sim, 1.2, trace)
    pos = np.array([p[0] for _, p, _ in trace])
    vel = np.array([v[0] for _, _, v in trace])
    assert pos[-1] == 1.0
    assert np.abs(vel).max() <= j.velocity + 1e-9
    t_reach = next(t for t, p, _ in trace if abs(p[0] - 1.0) < 1e-3)
    # d/v = 0.333 s; the servo's lag (0.02 s) adds to it; no trapezoid ramp (0.3 s)
    assert 1.0 / j.velocity < t_reach < 1.0 / j.velocity + 0.15
    assert np.all(np.diff(pos) >= -1e-12)


def test_tracks_goal_within_velocity_and_acceleration_limits(sim, desc):
    """The default: the description's acceleration limit, as dynamixel_driver writes it
    into each servo's Profile Acceleration."""
    j = desc.joints[0]
    sim.command(["joint1"], [1.0])
    trace: list = []
    run(sim, 1.2, trace)
    pos = np.array([p[0] for _, p, _ in trace])
    vel = np.array([v[0] for _, _, v in trace])
    assert pos[-1] == 1.0                                   # exactly on the goal
    assert np.abs(vel).max() <= j.velocity + 1e-9
    assert np.abs(np.diff(vel) / DT).max() <= j.acceleration + 1e-6
    # A trapezoid needs v/a + d/v = 0.3 + 0.333 s; the lag adds to it.
    t_reach = next(t for t, p, _ in trace if abs(p[0] - 1.0) < 1e-3)
    assert 0.63 < t_reach < 0.9
    assert np.all(np.diff(pos) >= -1e-12)                    # no overshoot / oscillation


def test_goals_outside_limits_are_clamped(sim, desc):
    report = sim.command(["joint2", "joint3"], [10.0, -0.2])
    assert report.clamped == ("joint2",)
    assert sim.goal[1] == desc.joints[1].upper
    run(sim, 2.0)
    assert sim.position[1] == pytest.approx(desc.joints[1].upper, abs=1e-9)
    assert sim.position.max() <= max(j.upper for j in desc.joints) + 1e-12
    report = sim.command(["joint4"], [0.3], [100.0])          # effort over the stall torque
    assert "joint4" in report.clamped and sim.limit[3] == desc.joints[3].effort


@pytest.mark.parametrize("names, pos, eff, message", [
    (["joint1", "joint2"], [0.1, float("nan")], (), "non-finite position"),
    (["joint1"], [0.1, 0.2], (), "2 values for 1 joint names"),
    (["joint1", "elbow"], [0.1, 0.2], (), "unknown joint(s) ['elbow']"),
    (["joint1", "joint1"], [0.1, 0.2], (), "duplicate joint names"),
    (["joint1"], [], [math.inf], "non-finite effort"),
    (["joint1"], [], [], "neither positions nor efforts"),
])
def test_bad_commands_rejected_whole(sim, names, pos, eff, message):
    before = sim.goal.copy()
    with pytest.raises(JointStateError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        sim.command(names, pos, eff)
    run(sim, 0.05)
    assert np.array_equal(sim.goal, before)
    assert all(m is ControlMode.CURRENT_POSITION for m in sim.mode)


def test_gravity_effort_reported_in_position_mode(sim):
    run(sim, 0.05)
    data = sim.model.createData()
    gravity = pin.computeGeneralizedGravity(sim.model, data, np.zeros(9))
    assert abs(gravity[1]) > 1.0                       # the arm is horizontal at q = 0
    assert sim.effort[:9] == pytest.approx(gravity, abs=1e-9)


def test_current_limit_below_the_gravity_load_is_reported(sim):
    """The mock does not make an under-powered servo sag, but says that the robot would."""
    run(sim, 0.05)
    load = abs(sim.effort[1])                          # joint2 holds the horizontal arm
    sim.command(["joint2"], [0.0], [0.5 * load])
    run(sim, 0.05)
    events = [e for e in sim.take_events() if e.kind == "underpowered"]
    assert len(events) == 1 and events[0].detail.startswith("joint2: current limit")
    run(sim, 0.05)
    assert not [e for e in sim.take_events() if e.kind == "underpowered"]   # once
    sim.command(["joint2"], [0.0], [2.0 * load])       # enough: no report
    run(sim, 0.05)
    sim.command(["joint2"], [0.0], [0.5 * load])       # under-powered again: reported again
    run(sim, 0.05)
    assert [e.kind for e in sim.take_events()].count("underpowered") == 1


def test_torque_mode_against_gravity(desc):
    """Joint 2 in torque mode: the RNEA gravity torque holds it, no torque lets it fall the
    way gravity pulls, twice the torque lifts it the other way (the others hold)."""
    outcome = {}
    for label, factor in (("hold", 1.0), ("fall", 0.0), ("lift", 2.0)):
        sim = JointSim(desc, config())
        g = pin.computeGeneralizedGravity(sim.model, sim.model.createData(), np.zeros(9))[1]
        for _ in range(40):                       # 0.2 s, effort streamed at 200 Hz
            sim.command(["joint2"], [], [factor * g])
            sim.step(DT)
        assert sim.mode[1] is ControlMode.TORQUE
        assert sim.effort[1] == pytest.approx(factor * g)
        outcome[label] = sim.position[1]
    assert abs(g) > 1.0                           # the arm is horizontal at q = 0
    assert abs(outcome["hold"]) < 1e-3
    assert outcome["fall"] * -np.sign(g) > 0.02   # gravity's torque on the joint is -g
    assert outcome["lift"] * np.sign(g) > 0.02


def test_effort_watchdog_holds_position(desc):
    sim = JointSim(desc, config(), effort_timeout=0.2)
    g = pin.computeGeneralizedGravity(sim.model, sim.model.createData(), np.zeros(9))[1]
    sim.command(["joint2"], [], [g - 0.5])    # sagging slowly
    run(sim, 0.15)
    assert sim.mode[1] is ControlMode.TORQUE and sim.take_events() == []
    run(sim, 0.1)
    assert sim.mode[1] is ControlMode.CURRENT_POSITION     # back to position class
    events = sim.take_events()
    assert [e.kind for e in events] == ["watchdog"] and "joint2" in events[0].detail
    held = sim.position[1]
    run(sim, 0.5)
    assert sim.position[1] == pytest.approx(held, abs=1e-6)


def test_torque_off_goes_limp_and_reboot_clears_errors(sim):
    sim.set_torque(False)
    assert sim.torque_enabled() == [False] * 10
    sim.command(["joint1"], [1.0])            # accepted, but a servo without torque ignores it
    run(sim, 0.5)
    assert sim.position[0] == pytest.approx(0.0, abs=1e-6)
    assert abs(sim.position[1]) > 0.05        # joint 2 sags under gravity
    sim.set_torque(True)
    sagged = sim.position[1]
    run(sim, 0.5)
    assert sim.position[1] == pytest.approx(sagged, abs=1e-9)   # holds where it was
    assert sim.position[0] == pytest.approx(0.0, abs=1e-6)      # old goals were dropped
    sim.inject_error("joint5", "overload")
    with pytest.raises(MockCommandError, match="joint5"):
        sim.set_torque(True)
    assert sim.reboot([]) == ["joint5"]
    assert sim.errors == {} and sim.mode[4] is ControlMode.OFF
    sim.set_torque(True)
    with pytest.raises(JointStateError, match="unknown"):
        sim.reboot(["joint42"])


def test_overload_error_after_sustained_stall(desc):
    sim = JointSim(desc, config())
    sim.command(["joint2"], [0.0], [1.0])     # current limit 1 N·m < gravity load
    run(sim, 0.5)
    assert sim.errors == {}                   # current-based mode: limited, no error
    sim.command(ARM, [0.0] * 9)               # position only: the default limit (stall)
    sim.stall[1] = sim.limit[1] = sim.limit_cmd[1] = 1.0   # a weak servo (test only)
    run(sim, OVERLOAD_TIME + 0.1)
    assert sim.errors == {"joint2": "overload"} and sim.mode[1] is ControlMode.OFF


def test_hold_stops_motion_and_drops_efforts(sim):
    sim.command(["joint1"], [1.0])
    g = pin.computeGeneralizedGravity(sim.model, sim.model.createData(), np.zeros(9))[1]
    sim.command(["joint2"], [], [g])
    run(sim, 0.3)
    moving = sim.position[0]
    assert 0.0 < moving < 1.0
    sim.hold()
    assert sim.mode[1] is ControlMode.CURRENT_POSITION
    run(sim, 0.5)
    assert abs(sim.position[0] - moving) < 0.05      # lag + brake distance only
    assert sim.velocity[0] == 0.0


def test_hold_keeping_grip_leaves_a_closing_gripper_its_goal(sim):
    """The drivers' hold rule: the arm stops; a position-controlled gripper goes on to its
    goal (its squeeze is kept); an effort-controlled one is held."""
    names = list(sim.names)
    sim.command(["gripper"], [1.2])
    run(sim, 2.0)
    sim.command(["joint1", "gripper"], [1.0, 0.0], [0.0, 0.3])
    run(sim, 0.2)
    moving = sim.position[0]
    assert "gripper" not in sim.hold_keeping_grip(names)
    run(sim, 2.0)
    assert abs(sim.position[0] - moving) < 0.05 and sim.position[-1] < 0.01
    sim.command(["gripper"], [1.2])
    run(sim, 2.0)
    sim.command(["gripper"], [], [-0.2])
    run(sim, 0.1)
    assert "gripper" in sim.hold_keeping_grip(names)
    stopped = sim.position[-1]
    run(sim, 0.5)
    assert abs(sim.position[-1] - stopped) < 0.05 and stopped > 0.3


def test_state_latency_and_noise(desc):
    sim = JointSim(desc, config(state_latency=0.05, position_noise=0.001))
    sim.command(["joint1"], [1.0])
    truth = []
    for _ in range(100):
        sim.step(DT)
        truth.append((sim.time, sim.position[0]))
    s = sim.state()
    assert s.stamp == pytest.approx(sim.time - 0.05)
    old = dict((round(t, 6), p) for t, p in truth)[round(s.stamp, 6)]
    errs = np.array([sim.state().position[0] - old for _ in range(4000)])
    assert abs(errs.mean()) < 4 * 0.001 / math.sqrt(4000)
    assert errs.std() == pytest.approx(0.001, rel=0.1)


def test_command_latency(desc):
    sim = JointSim(desc, config(command_latency=0.04))
    sim.command(["joint1"], [1.0])
    run(sim, 0.035)
    assert sim.goal[0] == 0.0 and sim.position[0] == 0.0
    run(sim, 0.01)
    assert sim.goal[0] == 1.0


def test_repeatability_offset_is_hidden_from_joint_states(desc):
    cfg = load_mock_config()   # the default work cell: repeatability on
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(cfg.imperfections, seed=3))
    sim = JointSim(desc, cfg)
    errors = []
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(-1.0, 1.0, 9)
        sim.command(ARM, q.tolist())
        run(sim, 1.5)
        assert sim.state().position[:9] == pytest.approx(q, abs=1e-9)   # encoders: perfect
        errors.append(np.linalg.norm(sim.tool_pose()[:3, 3] - desc.dh_forward(q)[:3, 3]))
    rms = math.sqrt(np.mean(np.square(errors)))
    # worse than the hole's 2 mm radial clearance: a blind drop onto the peg mostly fails
    assert rms > cfg.world.clearance("destination")
    assert rms < 0.03


def test_rail_variant_homing_and_setpoints():
    desc = load_description(variant="rail_arm")
    sim = JointSim(desc, config())
    assert sim.names[0] == "rail" and len(sim.names) == 11
    with pytest.raises(MockCommandError, match="not homed"):
        sim.command(["rail"], [0.2])
    # arm + rail before homing: as the real pair (the PMAC driver refuses its part, the
    # Dynamixel driver applies its joints), the arm's part applies, the rail's does not
    report = sim.command(["rail", "joint1"], [0.2, 0.1])
    assert "not homed" in report.rejected and report.applied == ("joint1",)
    assert sim.goal[0] == 0.0 and sim.goal[1] == 0.1
    sim.set_torque(False)
    with pytest.raises(MockCommandError, match="not enabled"):
        sim.home_rail()
    sim.set_torque(True)
    sim.home_rail()
    run(sim, 0.05)
    assert sim.homed
    sim.command(["rail"], [0.5])
    run(sim, 2.5)
    assert sim.position[0] == pytest.approx(0.5, abs=1e-9)
    assert np.abs(sim.velocity[0]) <= desc.rail.velocity
    with pytest.raises(MockCommandError, match="outside"):
        sim.command(["rail"], [2.0])
    with pytest.raises(MockCommandError, match="position-controlled"):
        sim.command(["rail"], [], [10.0])
    # efforts of 0 (many tools fill them) include the rail: no extra limit, accepted
    report = sim.command(["rail", "joint1"], [0.4, 0.2], [0.0, 0.0])
    assert report.rejected == "" and sim.goal[0] == 0.4 and sim.goal[1] == 0.2
    assert sim.limit_cmd[1] == sim.default_limit[1]
    # a non-zero rail effort: the rail's part refused whole, the arm's applied
    report = sim.command(["rail", "joint1"], [0.45, 0.3], [1.0, 0.5])
    assert "position-controlled" in report.rejected
    assert sim.goal[0] == 0.4 and sim.goal[1] == 0.3 and sim.limit_cmd[1] == 0.5
    with pytest.raises(JointStateError, match="non-finite"):   # NaN anywhere: all refused
        sim.command(["rail", "joint1"], [math.nan, 0.1])
    assert sim.goal[1] == 0.3
