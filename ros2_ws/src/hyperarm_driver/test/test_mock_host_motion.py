"""Core tier: the mock's host motion (hyperarm_driver.mock.host_motion), no ROS.

The rail sweep's profile and the rail following it; the smooth ramp (no jump, back to rest
exactly); the root acceleration put into the model's gravity against finite differences of
the pose; gravity along world -z under tilt (efforts); the work cell fixed in world (a
resting block and the camera's truth stay put, a pole meets a link only because the base
sways); the passive mount against the closed-form spring-damper response and its static
deflection against the arm's weight moment; the YAML schema.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.model import load_description
from hyperarm_description.pinocchio_model import build_model
from hyperarm_description.world import PoleSpec
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.host_motion import (GRAVITY, HostMotion, HostMotionConfigError,
                                              HostMotionError, HostMotionSpec, MountSpec,
                                              Oscillation, PassiveMount, Phase, RailSweep,
                                              Ramp, load_host_motion, parse_host_motion,
                                              shipped_host_motions, smootherstep)
from hyperarm_driver.mock.joint_sim import JointSim, MockCommandError

pytestmark = pytest.mark.core

DT = 0.005
ARM = [f"joint{i}" for i in range(1, 10)]


def config(**world):
    """The packaged cell, ideal servos (no current model: efforts are the true torques), no
    repeatability."""
    cfg = load_mock_config()
    cfg = dataclasses.replace(
        cfg, imperfections=dataclasses.replace(cfg.imperfections, repeatability=0.0, seed=1),
        current=dataclasses.replace(cfg.current, enabled=False))
    if world:
        cfg = dataclasses.replace(cfg, world=dataclasses.replace(
            cfg.world, spec=dataclasses.replace(cfg.world.spec, **world)))
    return cfg


@pytest.fixture(scope="module")
def arm():
    return load_description()


def hosted(desc, spec: HostMotionSpec, initial=None, require_homing=True, **world) -> JointSim:
    sim = JointSim(desc, config(**world), initial=initial, require_homing=require_homing)
    sim.host = HostMotion(spec, sim)
    return sim


def run(sim: JointSim, seconds: float, each=None, dt: float = DT) -> None:
    for _ in range(int(round(seconds / dt))):
        sim.step(dt)
        if each is not None:
            each()


# -- the profiles -----------------------------------------------------------------------------
def test_rail_sweep_profile_is_continuous_and_within_its_limits():
    sweep = RailSweep(amplitude=0.2, speed=0.2, acceleration=0.5)
    assert sweep.period == pytest.approx(2 * (0.32 / 0.2 + 0.8))   # 4.8 s
    tau = np.arange(0.0, 2 * sweep.period, 1e-3)
    x, v, a = np.array([sweep.position(t) for t in tau]).T
    assert x[0] == pytest.approx(0.0, abs=1e-12) and v[0] == pytest.approx(0.2)
    assert x.max() == pytest.approx(0.2, abs=1e-6) and x.min() == pytest.approx(-0.2, abs=1e-6)
    assert np.abs(v).max() <= 0.2 + 1e-12 and np.abs(a).max() <= 0.5 + 1e-12
    # the derivatives are the derivatives (no jump in position or velocity anywhere)
    assert np.abs(np.diff(x) - 1e-3 * 0.5 * (v[1:] + v[:-1])).max() < 1e-7
    assert np.abs(np.diff(v)).max() <= 0.5 * 1e-3 + 1e-9
    with pytest.raises(HostMotionConfigError, match="rail.acceleration"):
        RailSweep(amplitude=0.05, speed=0.5, acceleration=0.5)   # cannot turn around


def test_smootherstep_ramp_starts_and_ends_flat_and_reverses_without_a_jump():
    assert smootherstep(0.0) == (0.0, 0.0, 0.0) and smootherstep(1.0) == (1.0, 0.0, 0.0)
    ramp = Ramp(2.0)
    ramp.start()
    values = []
    for _ in range(300):                       # 1.5 s in, then reversed midway
        ramp.step(DT)
        values.append(ramp.value())
    assert ramp.phase is Phase.RAMP_IN
    ramp.stop()
    for _ in range(400):
        ramp.step(DT)
        values.append(ramp.value())
    s = np.array([v[0] for v in values])
    assert ramp.phase is Phase.OFF and s[-1] == 0.0
    assert np.abs(np.diff(s)).max() < 1.875 / 2.0 * DT * 1.01   # |ds/dt| <= 15/8 / T
    ramp.start()
    for _ in range(500):
        ramp.step(DT)
    assert ramp.phase is Phase.ON and ramp.value() == (1.0, 0.0, 0.0)


# -- the rail sweep in the simulation --------------------------------------------------------------
def test_rail_follows_the_sweep_while_the_arm_is_commanded_separately():
    desc = load_description(None, "rail_arm")
    sim = hosted(desc, load_host_motion("rail_sweep"))
    with pytest.raises(HostMotionError, match="not homed"):
        sim.host.enable()
    sim.home_rail()
    run(sim, 0.5, dt=0.01)
    assert sim.homed
    sim.host.enable()
    sim.command(["joint2"], [0.3])               # the arm: commanded on its own
    with pytest.raises(MockCommandError, match="scripted host motion"):
        sim.command(["rail"], [0.1])
    with pytest.raises(MockCommandError, match="scripted host motion"):
        sim.home_rail()
    trace = []
    run(sim, 7.0, lambda: trace.append((sim.position[0], sim.velocity[0])), dt=0.01)
    x, v = np.array(trace).T
    assert x.max() == pytest.approx(0.2, abs=0.004) and x.min() == pytest.approx(-0.2, abs=0.004)
    assert np.abs(v).max() <= 0.2 + 1e-6                  # ramped: never faster than 0.2 m/s
    assert sim.position[sim.names.index("joint2")] == pytest.approx(0.3)
    # host_pose on rail_arm: base_link with the carriage's travel
    assert sim.host.base_pose[0, 3] == pytest.approx(sim.position[0], abs=1e-9)
    sim.host.disable()
    run(sim, 2.5, dt=0.01)
    assert sim.host.phase is Phase.OFF and sim.velocity[0] == 0.0
    sim.command(["rail"], [0.1])                          # its own again
    run(sim, 1.5, dt=0.01)
    assert sim.position[0] == pytest.approx(0.1, abs=1e-6)
    # a sweep leaving the rail's range (±1.5 m) is refused
    near_end = hosted(desc, load_host_motion("rail_sweep"), initial={"rail": 1.4},
                      require_homing=False)
    with pytest.raises(HostMotionError, match="range"):
        near_end.host.enable()


def test_rail_losing_its_torque_stops_the_sweep():
    desc = load_description(None, "rail_arm")
    sim = hosted(desc, load_host_motion("rail_sweep"))
    sim.home_rail()
    run(sim, 0.5)
    sim.host.enable()
    run(sim, 1.0)
    sim.set_torque(False, ["rail"])
    run(sim, 0.1)
    assert sim.host.phase is Phase.OFF and "lost its torque" in sim.host.last_abort
    assert [e.kind for e in sim.take_events()].count("host_motion_stopped") == 1


# -- the base's motion ---------------------------------------------------------------------------------
def test_base_sway_ramps_in_smoothly_and_returns_exactly_to_rest(arm):
    sim = hosted(arm, load_host_motion("uav_sway"))
    run(sim, 0.2)
    assert np.array_equal(sim.host.base_pose, np.eye(4))      # configured, not enabled
    sim.host.enable()
    poses, gravity = [], []
    run(sim, 3.0, lambda: (poses.append(sim.host.base_pose.copy()),
                           gravity.append(sim.model.gravity.vector.copy())))
    p = np.array([m[:3, 3] for m in poses])
    tilt = np.degrees(np.arccos(np.clip([m[2, 2] for m in poses], -1.0, 1.0)))
    late = slice(int(2.0 / DT), None)      # after the 2 s ramp: half a period, every peak
    assert np.abs(p[late, 0]).max() == pytest.approx(0.02, rel=0.01)
    assert np.abs(p[late, 2]).max() == pytest.approx(0.01, rel=0.01)
    assert tilt[late].max() == pytest.approx(5.0, abs=0.05)
    # no jump: the second differences are bounded by the motion's acceleration bound
    # (amplitude x (ω² + 2 ω max ds/dt + max d²s/dt²), x axis)
    w = math.pi
    bound = 0.02 * (w * w + 2 * w * 1.875 / 2.0 + 5.78 / 4.0)
    acc = np.diff(p[:, 0], 2) / DT ** 2
    assert np.abs(acc).max() <= bound
    assert np.abs(acc[:5]).max() < 0.01 * bound               # starts from rest
    # the root's acceleration in the model's gravity (g - a) against finite differences of
    # the pose (linear; the root origin = base_link's on the arm variant)
    g = np.array(gravity)
    a_model = GRAVITY - g[:, :3]
    alpha_model = -g[:, 3:]
    k = np.arange(2, len(poses) - 2)
    a_fd = (p[k + 1] - 2 * p[k] + p[k - 1]) / DT ** 2
    # the linear part is at the world origin: a_origin = a_root - alpha x p_root
    a_root = a_model[k] + np.cross(alpha_model[k], p[k])
    assert np.abs(a_root - a_fd).max() < 2e-3 * np.abs(a_fd).max() + 1e-6
    rot = [m[:3, :3] for m in poses]
    omega = np.array([pin.log3(rot[i + 1] @ rot[i - 1].T) / (2 * DT) for i in range(1, len(rot) - 1)])
    alpha_fd = (omega[2:] - omega[:-2]) / (2 * DT)
    assert np.abs(alpha_model[2:-2] - alpha_fd).max() < 5e-3 * np.abs(alpha_fd).max()
    sim.host.disable()
    run(sim, 2.0 + DT)
    assert sim.host.phase is Phase.OFF
    assert np.array_equal(sim.host.base_pose, np.eye(4))
    assert np.array_equal(sim.model.gravity.vector, np.r_[GRAVITY, 0.0, 0.0, 0.0])


def test_efforts_see_gravity_along_world_z_under_tilt(arm):
    tilt = HostMotionSpec(name="tilt", ramp=1.0, base=(
        Oscillation("roll", 0.2, 0.02, math.pi / 2),))        # ~0.2 rad, slow (0.02 Hz)
    sim = hosted(arm, tilt, block=None)
    q = np.zeros(9)
    q[1], q[3] = 0.5, -0.4
    sim.command(ARM, q.tolist())
    run(sim, 1.5)
    untilted = sim.effort[:9].copy()
    sim.host.enable()
    run(sim, 1.2)
    rot = sim.host.base_pose[:3, :3]
    roll = math.atan2(rot[2, 1], rot[2, 2])
    assert roll == pytest.approx(0.2, abs=0.003)
    # reference: a model in base axes with gravity rotated into them
    model = build_model(arm)
    model.gravity = pin.Motion(rot.T @ GRAVITY, np.zeros(3))
    ref = pin.rnea(model, model.createData(), sim.position[:9], np.zeros(9), np.zeros(9))
    assert np.abs(sim.effort[:9] - ref).max() < 5e-3             # N·m
    assert np.abs(sim.effort[:9] - untilted).max() > 0.1          # the tilt shows


def test_work_cell_stays_fixed_in_world_while_the_base_sways(arm):
    sim = hosted(arm, load_host_motion("uav_sway"))
    truth0 = sim.truth()
    block0 = sim.world.block_pose()
    tool0 = sim.tool_pose()
    sim.host.enable()
    moved = []
    run(sim, 3.0, lambda: moved.append(np.linalg.norm(sim.tool_pose()[:3, 3] - tool0[:3, 3])),
        dt=0.01)
    assert max(moved) > 0.02                                   # the arm holds, its tool moves
    assert np.array_equal(sim.world.block_pose(), block0)      # the resting block stays put
    truth = sim.truth()
    assert truth.keys() == truth0.keys()
    assert all(np.array_equal(truth[k], truth0[k]) for k in truth)   # so the camera's truth
    assert not sim.link_contacts


def test_a_pole_meets_the_link_only_because_the_base_sways(arm):
    """The stretched arm (link capsules 25 mm) 5 mm beside a pole: no contact at rest; the
    2 cm sway along y brings the pole into the links (contacts computed in world)."""
    sway = HostMotionSpec(name="y", ramp=0.5, base=(Oscillation("y", 0.02, 0.5),))
    pole = PoleSpec(name="pole1", xy=(0.3, 0.025 + 0.01 + 0.005), radius=0.01,
                    z_min=-0.2, z_max=0.4)
    sim = hosted(arm, sway, poles=(pole,))
    run(sim, 0.3, dt=0.01)
    assert not sim.link_contacts
    sim.host.enable()
    touched = []
    run(sim, 1.2, lambda: touched.extend(sim.link_contacts), dt=0.01)
    assert touched and {c[1] for c in touched} == {"pole1"}
    force = max((c[3] for c in touched), key=np.linalg.norm)
    assert force[1] < 0.0                       # the pole pushes the links back towards -y


# -- the passive mount ---------------------------------------------------------------------------------
def _mount(k: float, c: float, m: float) -> tuple[PassiveMount, np.ndarray]:
    spec = MountSpec(mass=m, inertia=(0.01, 0.01, 0.01), stiffness=(k,) * 3 + (100.0,) * 3,
                     damping=(c,) * 3 + (1.0,) * 3)
    return PassiveMount(spec), np.diag([m] * 3 + [0.01] * 3)


def test_passive_mount_oscillates_as_the_closed_form_predicts():
    """Free vibration from a 2 mm displacement, ζ = 0.1 at 4 Hz: x0 e^(-ζωt) (cos ω_d t +
    ζω/ω_d sin ω_d t), at the node's 100 Hz step."""
    k, c, m, x0, h = 1200.0, 9.5, 1.9, 0.002, 0.01
    mount, mass = _mount(k, c, m)
    mount.displacement[2] = x0
    mount.acceleration[2] = -k * x0 / m
    wn = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = wn * math.sqrt(1 - zeta ** 2)
    errors, z = [], []
    for n in range(1, int(1.5 / h) + 1):
        mount.step(h, mass, np.zeros(6))
        t = n * h
        ref = x0 * math.exp(-zeta * wn * t) * (math.cos(wd * t)
                                               + zeta * wn / wd * math.sin(wd * t))
        errors.append(mount.displacement[2] - ref)
        z.append(mount.displacement[2])
    assert np.abs(errors).max() < 0.005 * x0                  # within 0.5 % of x0
    assert min(z) < -0.5 * x0                                  # it does swing back
    assert np.abs(mount.displacement[[0, 1, 3, 4, 5]]).max() == 0.0


def test_passive_mount_step_load_overshoots_and_settles_as_predicted():
    k, c, m, f, h = 1200.0, 9.5, 1.9, 3.0, 0.01
    mount, mass = _mount(k, c, m)
    zeta = c / (2 * math.sqrt(k * m))
    z = []
    for _ in range(int(3.0 / h)):
        mount.step(h, mass, np.array([0.0, 0.0, f, 0.0, 0.0, 0.0]))
        z.append(mount.displacement[2])
    overshoot = math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))   # 0.73
    assert max(z) / (f / k) == pytest.approx(1 + overshoot, rel=0.01)
    assert mount.displacement[2] == pytest.approx(f / k, rel=1e-3)


def test_passive_mount_settles_at_the_deflection_of_the_arms_weight_moment():
    """On rail_arm (the mount carries rail and arm), joint1 turned: the static deflection
    after lifting the arm is K⁻¹ x the change of the weight's wrench at the root, from the
    centre of mass alone; base_link (host_pose) shows it."""
    desc = load_description(None, "rail_arm")
    spec = HostMotionSpec(name="mount", ramp=0.5, mount=MountSpec(
        mass=0.5, inertia=(0.002,) * 3, stiffness=(1200.0,) * 3 + (150.0,) * 3,
        damping=(60.0,) * 3 + (2.0,) * 3))                     # well damped: settles fast
    sim = hosted(desc, spec, block=None)
    model = build_model(desc)
    data = model.createData()

    def weight_wrench() -> np.ndarray:
        """The robot's and the mount body's weight at the root, in its axes (from the COM)."""
        g = sim.host.root_pose()[:3, :3].T @ GRAVITY
        com = pin.centerOfMass(model, data, sim.position[:sim.nk])
        mass = sum(i.mass for i in model.inertias)
        return np.r_[(mass + 0.5) * g, np.cross(com, mass * g)]

    q = np.zeros(9)
    q[0] = 0.8                                                # joint1 turned: off the x axis
    sim.command(ARM, q.tolist())
    run(sim, 1.0, dt=0.01)                                    # there, at rest
    sim.host.enable()
    run(sim, 0.6, dt=0.01)
    before = weight_wrench()
    assert np.abs(sim.host.mount.displacement).max() < 1e-9   # preloaded: no sag
    q[1] = -0.6                                               # lift the stretched arm
    sim.command(ARM, q.tolist())
    run(sim, 2.5, dt=0.01)
    d = sim.host.mount.displacement
    expected = (weight_wrench() - before) / np.array(spec.mount.stiffness)
    assert abs(expected[3]) > 0.003 and abs(expected[4]) > 0.003   # roll and pitch (rad)
    assert np.abs(d - expected).max() < 0.02 * np.abs(expected).max()
    assert np.abs(sim.host.mount.velocity).max() < 1e-3        # settled
    # base_link (on the carriage, 5 cm up) turned by the mount's rotation in world
    rot = sim.host.base_pose[:3, :3]
    assert np.allclose(pin.log3(rot), d[3:], rtol=0.0, atol=1e-5)
    assert np.allclose(sim.host.base_pose[:3, 3], sim.host.root_pose()[:3, :3] @ [0, 0, 0.05]
                       + sim.host.root_pose()[:3, 3], rtol=0.0, atol=1e-12)


# -- the YAML ------------------------------------------------------------------------------------------
def test_shipped_host_motions_load():
    assert shipped_host_motions() == ["rail_sweep", "uav_sway", "uav_sway_passive"]
    specs = {n: load_host_motion(n) for n in shipped_host_motions()}
    assert specs["rail_sweep"].rail == RailSweep(0.2, 0.2, 0.5)
    assert specs["uav_sway_passive"].mount is not None
    assert specs["uav_sway"].base == specs["uav_sway_passive"].base


@pytest.mark.parametrize("text, field", [
    ("base: [{axis: x, amplitude: 0.02, frequency: 0.5}]", "schema_version"),
    ("schema_version: 1\nbase: [{axis: w, amplitude: 0.02, frequency: 0.5}]", "base[0].axis"),
    ("schema_version: 1\nbase: [{axis: x, amplitude: -1, frequency: 0.5}]",
     "base[0].amplitude"),
    ("schema_version: 1\nbase: [{axis: x, amplitude: .nan, frequency: 0.5}]",
     "base[0].amplitude"),
    ("schema_version: 1\nbase: [{axis: roll, amplitude: 1.0, frequency: 0.5}]",
     "base[0].amplitude: at most"),
    ("schema_version: 1\nbase: [{axis: x, amplitude: 0.02, frequency: 0.5, speed: 1}]",
     "base[0]: unknown field(s) ['speed']"),
    ("schema_version: 1\nrail: {amplitude: 0.2, speed: 0.2, acceleration: 0.01}",
     "rail.acceleration"),
    ("schema_version: 1\nmount: {mass: 1, inertia: [1, 1, 1], stiffness: [1, 1], "
     "damping: [0, 0, 0, 0, 0, 0]}", "mount.stiffness"),
    ("schema_version: 1\nramp: 2.0", "give at least one of rail, base, mount"),
    ("schema_version: 2\nbase: [{axis: x, amplitude: 0.02, frequency: 0.5}]",
     "schema_version"),
])
def test_bad_host_motion_yaml_is_refused_naming_the_field(text, field):
    import yaml

    with pytest.raises(HostMotionConfigError) as err:
        parse_host_motion(yaml.safe_load(text), source="bad.yaml")
    assert str(err.value).startswith("bad.yaml: ") and field in str(err.value), str(err.value)


def test_rail_sweep_on_the_arm_variant_is_refused(arm):
    with pytest.raises(HostMotionConfigError, match="rail: the arm variant has no rail"):
        hosted(arm, load_host_motion("rail_sweep"))
