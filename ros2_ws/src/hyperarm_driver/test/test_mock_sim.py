"""Core tier: the simulated servos (tracking, limits, bad input, watchdog, torque mode against
gravity, torque off, reboot, latency, noise, rail homing). No ROS.

The joints are MuJoCo's (mock/physics.py): a position-class servo is a PD (kp, kv) on its
profile with the arm's gravity, inertia and friction fed forward, acting once per MuJoCo
step, so it is not exactly on its reference: moving, it is off by up to the profile's travel
in one step; at rest its Coulomb friction holds it up to coulomb/kp away; after a
disturbance it swings back like a spring. The checks below state those physical bounds from
the simulation's own parameters."""
from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.joints import JointStateError
from hyperarm_description.mjcf import FINGER_MASS
from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import (OVERLOAD_TIME, ControlMode, JointSim,
                                            MockCommandError)

pytestmark = pytest.mark.core

DT = 0.005
ARM = [f"joint{i}" for i in range(1, 10)]


def config(current: bool = False, friction: bool = False, **imperfections):
    """The packaged cell without repeatability; ideal servos (no current model, no torque
    gap at a mode switch) unless ``current``: those have their own tests
    (test_mock_servo.py). ``friction``: ideal servos but for their Coulomb friction (the
    current model with an exact torque constant and no current quantum), which stops a
    position servo within coulomb/kp of its goal (a frictionless one swings about it)."""
    cfg = load_mock_config()
    imp = dataclasses.replace(cfg.imperfections, repeatability=0.0, seed=1, **imperfections)
    cur = dataclasses.replace(cfg.current, enabled=current or friction)
    if friction and not current:
        cur = dataclasses.replace(cur, torque_constant_error=0.0, quantum=0.0)
    return dataclasses.replace(
        cfg, imperfections=imp, current=cur,
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
            record.append((sim.time, sim.position.copy(), sim.velocity.copy(),
                           sim._ref.copy()))


def gravity(sim, q) -> np.ndarray:
    """Gravity torques (N·m) on the arm joints at ``q``: pinocchio's, of the description,
    plus the MuJoCo model's two fingers (not in the description's chain), hanging at
    tool0."""
    model = sim.model
    data = model.createData()
    g = pin.computeGeneralizedGravity(model, data, np.asarray(q, dtype=float))
    jac = pin.computeFrameJacobian(model, data, np.asarray(q, dtype=float), sim.tool_id,
                                   pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    return g + jac.T @ np.array([0.0, 0.0, 2 * FINGER_MASS * 9.81])


def inertia(sim, i: int) -> float:
    """Joint ``i``'s inertia (kg·m², kg) at the present posture (MuJoCo's, armature
    included), the others held."""
    return float(sim.physics.inertia_times(np.eye(sim.n)[i])[i])


def band(sim, i: int, speed: float = 0.0) -> float:
    """How far a position servo may be from its reference (rad, m): its Coulomb friction
    holds it up to coulomb/kp away, and moving at ``speed`` it acts once per MuJoCo step:
    off by up to the reference's travel in one step."""
    return sim.coulomb[i] / sim._kp[i] + abs(speed) * sim.physics.timestep


def swing(sim, i: int, speed: float) -> float:
    """How far past its reference a position servo can carry a joint moving at ``speed``
    when the reference stops: the spring kp takes the kinetic energy, ½·I·v² = ½·kp·x²
    (damping and friction only take some off), plus the friction band."""
    return abs(speed) * math.sqrt(inertia(sim, i) / sim._kp[i]) + band(sim, i)


def test_profile_acceleration_0_is_velocity_limited_only(desc):
    """A servo's Profile Acceleration 0 (unlimited): the profile (the servo's reference, a
    Dynamixel's Position Trajectory) moves at the velocity limit from the first step,
    straight to the goal, without overshoot. The stretched arm's joint follows it as its
    torque limit allows."""
    j = desc.joints[0]
    cfg = config()
    sim = JointSim(desc, dataclasses.replace(
        cfg, servo=dataclasses.replace(cfg.servo, profile_acceleration=0.0)))
    sim.command(["joint1"], [1.0])
    trace: list = []
    run(sim, 1.2, trace)
    ref = np.array([r[0] for *_, r in trace])
    assert ref[-1] == 1.0
    speed = np.diff(np.r_[0.0, ref]) / DT
    arrive = int(np.argmax(ref == 1.0))          # the first sample on the goal: d/v
    assert 1.0 / j.velocity <= trace[arrive][0] < 1.0 / j.velocity + DT
    assert speed[:arrive] == pytest.approx(j.velocity, abs=1e-9)   # no ramp (0.3 s)
    assert np.all(np.diff(ref) >= 0.0)
    # the joint: lags while its torque limit accelerates the arm, then gets there
    t_reach = next(t for t, p, *_ in trace if p[0] > 1.0 - 1e-3)
    assert 1.0 / j.velocity < t_reach < 1.0 / j.velocity + 0.15


def test_tracks_goal_within_velocity_and_acceleration_limits(sim, desc):
    """The default: the description's acceleration limit, as dynamixel_driver writes it
    into each servo's Profile Acceleration. The profile is exact; the joint follows it
    within its tracking band."""
    j = desc.joints[0]
    sim.command(["joint1"], [1.0])
    trace: list = []
    run(sim, 1.2, trace)
    ref = np.array([r[0] for *_, r in trace])
    pos = np.array([p[0] for _, p, _, _ in trace])
    vel = np.diff(np.r_[0.0, ref]) / DT
    assert ref[-1] == 1.0                                   # exactly on the goal
    assert np.abs(vel).max() <= j.velocity + 1e-9
    assert np.abs(np.diff(vel) / DT).max() <= j.acceleration + 1e-6
    assert np.all(np.diff(ref) >= 0.0)                      # no overshoot
    # the joint within its band of the profile all along
    near = band(sim, 0, j.velocity)
    assert np.abs(pos - ref).max() <= near
    # A trapezoid needs v/a + d/v = 0.3 + 0.333 s: the joint gets there with its profile
    t_reach = next(t for t, p, *_ in trace if abs(p[0] - 1.0) < 1e-3)
    t_ref = next(t for t, _, _, r in trace if abs(r[0] - 1.0) < 1e-3 + near)
    assert t_ref <= t_reach < 0.9
    assert trace[int(np.argmax(ref == 1.0))][0] == pytest.approx(0.3 + 1.0 / 3.0, abs=DT)


def test_goals_outside_limits_are_clamped(desc):
    """(joint1: joint2 at its upper limit would put the stretched arm into the table.)"""
    sim = JointSim(desc, config(friction=True))
    report = sim.command(["joint1", "joint3"], [10.0, -0.2])
    assert report.clamped == ("joint1",)
    assert sim.goal[0] == desc.joints[0].upper
    top = -math.inf
    for _ in range(int(round(2.0 / DT))):
        sim.step(DT)
        top = max(top, sim.position[0])
    assert sim.position[0] == pytest.approx(desc.joints[0].upper, abs=band(sim, 0))
    assert sim.position[2] == pytest.approx(-0.2, abs=band(sim, 2))
    # never past the limit by more than the servo's tracking band (MuJoCo's joint limit
    # is a soft constraint)
    assert top <= desc.joints[0].upper + band(sim, 0, desc.joints[0].velocity)
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
    gravity_load = gravity(sim, np.zeros(9))
    assert abs(gravity_load[1]) > 1.0                  # the arm is horizontal at q = 0
    # at rest where it started, a frictionless servo's force is its feed-forward: the load
    assert sim.effort[:9] == pytest.approx(gravity_load, abs=1e-9)


def test_current_limit_below_the_gravity_load_sags_the_joint(desc):
    """A current limit below a joint's gravity load: the servo exerts its limit and the
    joint sags (on MuJoCo it really does; the old mock held it and only logged an
    ``underpowered`` event); with enough current it lifts the arm back to its goal."""
    sim = JointSim(desc, config(friction=True))
    run(sim, 0.05)
    load = sim.effort[1]                               # joint2 holds the horizontal arm
    sim.command(["joint2"], [0.0], [0.5 * abs(load)])
    run(sim, 0.3)
    assert abs(sim.effort[1]) == pytest.approx(sim.limit[1], rel=1e-9)   # at its limit
    assert sim.position[1] * -np.sign(load) > 0.05     # sagging the way gravity pulls
    sim.command(["joint2"], [0.0], [2.0 * abs(load)])  # enough: back up to the goal
    path = []
    for _ in range(int(round(0.5 / DT))):
        sim.step(DT)
        path.append(sim.position[1] * -np.sign(load))
    assert min(path) <= band(sim, 1)                   # (it swings about it: see the end)


def test_torque_mode_against_gravity(desc):
    """Joint 2 in torque mode: the gravity torque holds it, no torque lets it fall the way
    gravity pulls, twice the torque lifts it the other way (the others hold)."""
    outcome = {}
    for label, factor in (("hold", 1.0), ("fall", 0.0), ("lift", 2.0)):
        sim = JointSim(desc, config())
        g = gravity(sim, np.zeros(9))[1]
        for _ in range(40):                       # 0.2 s, effort streamed at 200 Hz
            sim.command(["joint2"], [], [factor * g])
            sim.step(DT)
        assert sim.mode[1] is ControlMode.TORQUE
        outcome[label] = sim.position[1]
        if label == "hold":                       # at rest: exactly the commanded torque
            assert sim.effort[1] == pytest.approx(g, abs=1e-9)
    assert abs(g) > 1.0                           # the arm is horizontal at q = 0
    assert abs(outcome["hold"]) < 1e-6
    assert outcome["fall"] * -np.sign(g) > 0.02   # gravity's torque on the joint is -g
    assert outcome["lift"] * np.sign(g) > 0.02


def test_current_mode_exerts_the_commanded_torque_while_moving(desc):
    """Joint 2 commanded no torque falls freely: its motor exerts none (the current loop
    holds the goal current; the back-EMF only limits the torque near the no-load speed)."""
    sim = JointSim(desc, config())
    for _ in range(10):
        sim.command(["joint2"], [], [0.0])
        sim.step(DT)
    assert 0.3 < abs(sim.velocity[1]) < sim.vmax[1]       # falling, below no-load speed
    assert sim.effort[1] == pytest.approx(0.0, abs=1e-9)


def test_effort_watchdog_holds_position(desc):
    sim = JointSim(desc, config(), effort_timeout=0.2)
    g = gravity(sim, np.zeros(9))[1]
    sim.command(["joint2"], [], [g - 0.2])    # sagging slowly
    run(sim, 0.15)
    assert sim.mode[1] is ControlMode.TORQUE and sim.take_events() == []
    sagging = sim.velocity[1]
    run(sim, 0.1)
    assert sim.mode[1] is ControlMode.CURRENT_POSITION     # back to position class
    events = sim.take_events()
    assert [e.kind for e in events] == ["watchdog"] and "joint2" in events[0].detail
    held = sim.goal[1]                                     # where the watchdog caught it
    assert abs(held) > 1e-3                                # it had sagged
    # the servo takes the sag's momentum like a spring (within its swing), then holds it
    # there; torque-controlled on, the 0.2 N·m short would have let it fall on
    bound = swing(sim, 1, max(abs(sagging), abs(sim.velocity[1])))
    worst = 0.0
    for _ in range(int(round(0.5 / DT))):
        sim.step(DT)
        worst = max(worst, abs(sim.position[1] - held))
    assert worst <= bound
    assert bound < 0.02


def test_torque_off_goes_limp_and_reboot_clears_errors(sim):
    sim.set_torque(False)
    assert sim.torque_enabled() == [False] * 10
    sim.command(["joint1"], [1.0])            # accepted, but a servo without torque ignores it
    run(sim, 0.5)
    assert sim.position[0] == pytest.approx(0.0, abs=1e-6)
    assert abs(sim.position[1]) > 0.05        # joint 2 sags under gravity
    sim.set_torque(True)
    sagged = sim.position[1]
    bound = swing(sim, 1, sim.velocity[1])    # still swinging as it is caught
    worst = 0.0
    for _ in range(int(round(0.5 / DT))):
        sim.step(DT)
        worst = max(worst, abs(sim.position[1] - sagged))
    assert worst <= bound < 0.05              # holds where it was
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
    g = gravity(sim, np.zeros(9))[1]
    sim.command(["joint2"], [], [g])
    run(sim, 0.3)
    moving, speed = sim.position[0], sim.velocity[0]
    assert 0.0 < moving < 1.0 and speed > 1.0
    sim.hold()
    assert sim.mode[1] is ControlMode.CURRENT_POSITION
    bound = swing(sim, 0, speed)              # the stop: the servo's spring takes it
    worst = 0.0
    for _ in range(int(round(0.5 / DT))):
        sim.step(DT)
        worst = max(worst, abs(sim.position[0] - moving))
    assert sim.goal[0] == moving              # held where it was, not on to 1.0
    assert worst <= bound and moving + worst < 1.0
    # how fast it comes to rest: test_a_held_joint_comes_to_rest_without_swinging


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
    # not moved: at rest where it started (to MuJoCo's rounding)
    assert sim.goal[0] == 0.0 and abs(sim.position[0]) < 1e-12
    run(sim, 0.01)
    assert sim.goal[0] == 1.0


def settle(sim, most: float) -> None:
    """Run until the arm is at rest (no joint faster than 1 mrad/s for 0.1 s), at most
    ``most`` s: a move its torque limits cannot follow rings for a while (see
    test_a_held_joint_comes_to_rest_without_swinging)."""
    for _ in range(int(round(most / 0.1))):
        fastest = 0.0
        for _ in range(int(round(0.1 / DT))):
            sim.step(DT)
            fastest = max(fastest, np.abs(sim.velocity[:sim.nk]).max())
        if fastest < 1e-3:
            return


def touches(sim, q) -> bool:
    """Whether the arm at joints ``q`` (rad) touches anything (the table, a peg, itself...;
    MuJoCo's contacts, on a scratch copy of the state): the block resting on its peg aside."""
    ph = sim.physics
    data = mujoco.MjData(ph.model)
    data.qpos[:] = ph.data.qpos
    data.qpos[ph._qadr[:len(q)]] = q
    mujoco.mj_forward(ph.model, data)
    cell = ("block_piece", "table", "peg_")
    return any(not (ph.geom_names[c.geom1].startswith(cell)
                    and ph.geom_names[c.geom2].startswith(cell))
               for c in data.contact[:data.ncon])


def test_repeatability_offset_is_hidden_from_joint_states(desc):
    cfg = load_mock_config()   # the default work cell: repeatability on
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(cfg.imperfections, seed=3))
    sim = JointSim(desc, cfg)
    errors = []
    rng = np.random.default_rng(0)
    q = np.zeros(9)
    for _ in range(10):               # (rms ~7 mm: 10 postures tell it from 2 and 30 mm)
        # a random posture nearby (a move the servos follow, not one that saturates them)
        # the arm gets to freely (MuJoCo's links meet the table and the pegs)
        start, q = q, np.clip(q + rng.uniform(-0.4, 0.4, 9), -1.0, 1.0)
        while any(touches(sim, start + s * (q - start)) for s in np.linspace(0.2, 1.0, 5)):
            q = np.clip(start + rng.uniform(-0.4, 0.4, 9), -1.0, 1.0)
        sim.command(ARM, q.tolist())
        run(sim, 0.3)
        settle(sim, 2.0)
        seen = sim.state().position
        assert np.array_equal(seen, sim.position)       # encoders: perfect, offset unseen
        # at the goals within the servos' friction band (MuJoCo's joints)
        assert np.all(np.abs(seen[:9] - q) <= [band(sim, i) for i in range(9)])
        # the tool where the true joints, the encoders' plus the hidden offset, put it
        true = sim.position[:9] + sim.offset[:9]
        # (MuJoCo's model: the description's numbers as its XML prints them, to 1 µm)
        assert sim.tool_pose()[:3, 3] == pytest.approx(desc.dh_forward(true)[:3, 3], abs=1e-6)
        errors.append(np.linalg.norm(sim.tool_pose()[:3, 3] - desc.dh_forward(q)[:3, 3]))
    rms = math.sqrt(np.mean(np.square(errors)))
    print(f"tool error rms {rms * 1e3:.1f} mm over {len(errors)} postures")
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
    while sim._ref[0] != 0.5:                 # the PMAC's profile, exactly on the setpoint
        sim.step(DT)
        assert sim.time < 2.0
    error, speed, end = abs(sim.position[0] - 0.5), abs(sim.velocity[0]), sim.time
    run(sim, 1.0)
    # the rail's position loop is overdamped (kv² > 4·kp·mass): from the profile's end its
    # error decays at least as fast as exp(-kp/kv·t), from the error and the velocity's
    # share kv/kp·v
    kp, kv = sim._kp[0], sim._kv[0]
    assert abs(sim.position[0] - 0.5) <= (error + speed * kv / kp) \
        * math.exp(-kp / kv * (sim.time - end))
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


def test_a_move_ends_on_its_goal_without_overshoot(desc):
    """With its friction (as every real servo has), a position servo ends a profiled move
    within its friction band of the goal, never past it by more."""
    sim = JointSim(desc, config(friction=True))
    sim.command(["joint1"], [1.0])
    trace: list = []
    run(sim, 1.2, trace)
    pos = np.array([p[0] for _, p, _, _ in trace])
    assert pos.max() <= 1.0 + band(sim, 0)
    assert abs(pos[-1] - 1.0) <= band(sim, 0)


@pytest.mark.xfail(strict=True, reason=(
    "engine defect left: the arm's position loops are a PD (critically damped for the "
    "stretched arm) without the firmware's integral action; held at 3 rad/s, joint1 comes "
    "back 1.08 mrad past the stop against a 0.77 mrad friction band (0.24 rad at the "
    "earlier fixed kv 0.5 N·m·s/rad)"))
def test_a_held_joint_comes_to_rest_without_swinging(desc):
    """Held while moving fast, a position servo overshoots the stop once, comes back to it
    without swinging past it, and is still a second later."""
    sim = JointSim(desc, config(friction=True))
    sim.command(["joint1"], [1.0])
    run(sim, 0.3)
    moving = sim.position[0]
    sim.hold()
    path = []
    for _ in range(int(round(1.0 / DT))):
        sim.step(DT)
        path.append(sim.position[0] - moving)
    assert min(path) >= -band(sim, 0)         # never back past the stop
    assert abs(sim.velocity[0]) < 1e-3 and abs(path[-1]) <= band(sim, 0)
