"""Core tier: the mock's host motion (hyperarm_driver.mock.host_motion), no ROS.

The rail sweep's profile and the rail's servo following it; the smooth ramp (no jump, back
to rest exactly); the root's acceleration as MuJoCo's d'Alembert forces against finite
differences of the pose; gravity along world -z under tilt (efforts); the work cell fixed in
world (a resting block and the camera's truth stay put, a pole meets a link only because the
base sways); the passive mount (MuJoCo's mount joints): preloaded it stays put at rest, its
free vibration at the frequency of its spring and the mass it carries, its static
deflection against the arm's weight moment; the YAML schema.
"""
from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.mjcf import FINGER_MASS, MOUNT_JOINTS
from hyperarm_description.model import load_description
from hyperarm_description.pinocchio_model import build_model
from hyperarm_description.world import PoleSpec
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.host_motion import (GRAVITY, HostMotion, HostMotionConfigError,
                                              HostMotionError, HostMotionSpec, MountSpec,
                                              Oscillation, Phase, RailSweep,
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
    j2 = sim.names.index("joint2")
    trace = []
    run(sim, 7.0, lambda: trace.append((sim.position[0], sim.velocity[0], sim.host.rail_target,
                                        sim.position[j2])), dt=0.01)
    x, v, target, q2 = np.array(trace).T
    assert x.max() == pytest.approx(0.2, abs=0.004) and x.min() == pytest.approx(-0.2, abs=0.004)
    # ramped: the sweep's profile is never faster than 0.2 m/s
    assert np.abs(np.diff(target)).max() <= 0.2 * 0.01 + 1e-12
    # the rail's servo follows it (MuJoCo's PD with feed-forward; its error dynamics
    # M ë + kv ė + kp e = f for a force f its feed-forward misses): even missing the whole
    # inertial force of the sweep's acceleration steps (f = M a, M the rail's inertia with
    # the arm on it), the error would stay under M a / kp and its rate, the loop being
    # overdamped, under M a / kv (measured: 0.05 mm, 0.5 mm/s at most)
    ph, r = sim.physics, sim.names.index("rail")
    unit = np.zeros(sim.n)
    unit[r] = 1.0
    force = ph.inertia_times(unit)[r] * load_host_motion("rail_sweep").rail.acceleration
    assert np.abs(x - target).max() < force / sim._kp[r]
    assert np.abs(v).max() <= 0.2 + force / sim._kv[r]
    # the arm, commanded on its own, holds joint2 at its goal but for the sweep's shaking:
    # the coupling torque of its acceleration on joint2 over the servo's stiffness (an
    # upper bound: the feed-forward carries most of it; measured ~1e-5 rad)
    unit[:] = 0.0
    unit[j2] = 1.0
    coupling = abs(ph.inertia_times(unit)[r]) * load_host_motion("rail_sweep").rail.acceleration
    assert np.abs(q2[len(q2) // 2:] - 0.3).max() < coupling / sim._kp[j2]
    # host_pose on rail_arm: base_link with the carriage's travel
    assert sim.host.base_pose[0, 3] == pytest.approx(sim.position[0], abs=1e-9)
    sim.host.disable()
    run(sim, 2.5, dt=0.01)
    # stopped (a physical servo at rest: no exact zero; ideal servos here, no friction band)
    assert sim.host.phase is Phase.OFF and abs(sim.velocity[0]) < 1e-6
    assert sim.position[j2] == pytest.approx(0.3, abs=1e-6)   # at its goal once still
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
def _applied_field(sim: JointSim) -> np.ndarray:
    """The acceleration field (a at the world origin, α; 6) that MuJoCo's applied forces on
    the robot's bodies put on it: each body gets -m (a + α × c) at its centre of mass c;
    solved by least squares over the bodies (zeros when no force is applied)."""
    ph = sim.physics
    m, d = ph.model, ph.data
    host = ph.body["host"]
    b = np.array([i for i in range(1, m.nbody) if i != host and m.body_mass[i] > 0.0
                  and m.body_rootid[i] == m.body_rootid[host]])
    c = d.xipos[b]
    rows = np.zeros((len(b), 3, 6))
    rows[:, :, :3] = np.eye(3)
    # a + α × c
    rows[:, 0, 4], rows[:, 0, 5] = c[:, 2], -c[:, 1]
    rows[:, 1, 3], rows[:, 1, 5] = -c[:, 2], c[:, 0]
    rows[:, 2, 3], rows[:, 2, 4] = c[:, 1], -c[:, 0]
    rhs = -d.xfrc_applied[b, :3] / m.body_mass[b][:, None]
    return np.linalg.lstsq(rows.reshape(-1, 6), rhs.ravel(), rcond=None)[0]


def test_base_sway_ramps_in_smoothly_and_returns_exactly_to_rest(arm):
    sim = hosted(arm, load_host_motion("uav_sway"))
    run(sim, 0.2)
    assert np.array_equal(sim.host.base_pose, np.eye(4))      # configured, not enabled
    sim.host.enable()
    poses, accels = [], []
    run(sim, 3.0, lambda: (poses.append(sim.host.base_pose.copy()),
                           accels.append(_applied_field(sim))))
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
    # the root's acceleration in MuJoCo's d'Alembert forces against finite differences of
    # the pose (linear; the root origin = base_link's on the arm variant)
    a_model = np.array([a[:3] for a in accels])
    alpha_model = np.array([a[3:] for a in accels])
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
    # no d'Alembert force left, gravity along world -z throughout
    assert not np.any(sim.physics.data.xfrc_applied)
    assert np.array_equal(sim.physics.model.opt.gravity, GRAVITY)


def test_efforts_see_gravity_along_world_z_under_tilt(arm):
    """The servos' efforts are the arm's dynamics with gravity along world -z in the tilted
    base: pinocchio's inverse dynamics in base axes, gravity rotated into them (plus what
    MuJoCo adds to the description: the rotors' armature, the joints' damping, the two
    fingers at tool0). Dynamics, not statics: the tilt's ramp sets the stretched arm
    swinging on its servos (kp 20 N·m/rad, damping ratio ~0.07: tenths of a N·m for
    seconds), so the reference takes MuJoCo's joint accelerations of that step."""
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
    ph = sim.physics
    m, d, dofs = ph.model, ph.data, ph._dadr[:9]
    q, qd = ph.q[:9].copy(), ph.qd[:9].copy()
    sim.step(ph.timestep)                    # one MuJoCo step from (q, qd): its qacc, efforts
    acc = d.qacc[dofs].copy()
    rot = sim.host.base_pose[:3, :3]
    roll = math.atan2(rot[2, 1], rot[2, 2])
    assert roll == pytest.approx(0.2, abs=0.003)
    model = build_model(arm)
    model.gravity = pin.Motion(rot.T @ GRAVITY, np.zeros(3))
    data = model.createData()
    ref = pin.rnea(model, data, q, qd, acc) + m.dof_armature[dofs] * acc \
        + m.dof_damping[dofs] * qd
    jac = pin.computeFrameJacobian(model, data, q, sim.tool_id,
                                   pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    ref -= jac.T @ (2 * FINGER_MASS * (rot.T @ GRAVITY))
    # what is left: the host's own (slow) motion's d'Alembert forces, the fingers' inertia
    assert np.abs(sim.effort[:9] - ref).max() < 5e-3             # N·m
    assert np.abs(sim.effort[:9] - untilted).max() > 0.1          # the tilt shows


def test_work_cell_stays_fixed_in_world_while_the_base_sways(arm):
    """The block resting on its peg and the camera's truth do exactly what they do without
    the sway (a twin simulation at rest: MuJoCo's resting block creeps by itself, ~1e-8 rad
    in 3 s, its contacts' softness; the sway adds nothing to it)."""
    sim = hosted(arm, load_host_motion("uav_sway"))
    still = hosted(arm, load_host_motion("uav_sway"))
    truth0 = sim.truth()
    tool0 = sim.tool_pose()
    sim.host.enable()
    moved = []

    def each() -> None:
        still.step(0.01)
        moved.append(np.linalg.norm(sim.tool_pose()[:3, 3] - tool0[:3, 3]))

    run(sim, 3.0, each, dt=0.01)
    assert max(moved) > 0.02                                   # the arm holds, its tool moves
    assert still.host.phase is Phase.OFF
    block = sim.world.block_pose()
    assert np.array_equal(block, still.world.block_pose())     # the resting block stays put
    assert np.abs(block[:3, 3] - truth0["block"][:3, 3]).max() < 1e-6   # (its creep: m)
    truth = sim.truth()
    assert truth.keys() == truth0.keys()
    assert all(np.array_equal(truth[k], still.truth()[k]) for k in truth)   # the camera's
    assert all(np.array_equal(truth[k], truth0[k]) for k in truth if k != "block")
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
SHIPPED_MOUNT = load_host_motion("uav_sway_passive").mount


def _mount_dofs(sim: JointSim) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's mount joints: their dof and qpos addresses (MOUNT_JOINTS' order)."""
    m = sim.physics.model
    joints = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in MOUNT_JOINTS]
    return m.jnt_dofadr[joints], m.jnt_qposadr[joints]


def test_preloaded_mount_stays_put_at_rest(arm):
    """The mount's springs carry the arm's weight from the start: at rest, configured and
    then enabled (no base motion), the base does not move; unpreloaded, the same weight
    would sag it by its load over the stiffness (millimetres, milliradians)."""
    spec = HostMotionSpec(name="mount", ramp=0.5, mount=SHIPPED_MOUNT)
    sim = hosted(arm, spec, initial={"joint2": 0.4, "joint4": -0.3})
    dofs, _ = _mount_dofs(sim)
    sag = np.abs(sim.physics.data.qfrc_bias[dofs]) / np.array(SHIPPED_MOUNT.stiffness)
    assert sag[2] > 1e-3                          # m: the weight the springs carry
    worst = []
    run(sim, 0.5, lambda: worst.append(np.abs(sim.host.mount.displacement).max()), dt=0.01)
    sim.host.enable()
    run(sim, 1.0, lambda: worst.append(np.abs(sim.host.mount.displacement).max()), dt=0.01)
    assert sim.host.phase is Phase.ON
    assert max(worst) < 1e-6 * sag.max()
    assert np.allclose(sim.host.base_pose, np.eye(4), rtol=0.0, atol=1e-6 * sag.max())


def test_mount_vibrates_at_the_frequency_of_its_spring_and_the_mass_it_carries(arm):
    """The shipped mount (8 kg airframe) plucked 2 mm along z with the arm upright: a free
    damped vibration at ω_d = sqrt(k/m) sqrt(1 - ζ²), m the airframe's mass plus the robot's
    (the description's links and MuJoCo's two fingers), ζ = c / (2 sqrt(k m)).

    Tolerance: the arm is not rigid (it hangs on its servos) and the mount's rotations are
    free: coupled to them, the z mode moves. By how much at most is the effective mass's
    range, from m (everything rigid) to the Schur complement of MuJoCo's mass matrix with
    every other degree of freedom free (arm joints, mount rotations): upright, ~1 %."""
    spec = HostMotionSpec(name="mount", ramp=0.5, mount=SHIPPED_MOUNT)
    sim = hosted(arm, spec, initial={"joint2": -math.pi / 2}, block=None)
    ph = sim.physics
    m, d = ph.model, ph.data
    dofs, qadr = _mount_dofs(sim)
    mass = SHIPPED_MOUNT.mass + sum(i.mass for i in sim.model.inertias) + 2 * FINGER_MASS
    k, c = SHIPPED_MOUNT.stiffness[2], SHIPPED_MOUNT.damping[2]
    zeta = c / (2.0 * math.sqrt(k * mass))
    predicted = math.sqrt(k / mass) * math.sqrt(1.0 - zeta ** 2)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    z = int(dofs[2])
    assert full[z, z] == pytest.approx(mass, rel=1e-9)       # MuJoCo carries that mass
    rest = [i for i in range(m.nv) if i != z]
    free = full[z, z] - full[z, rest] @ np.linalg.solve(full[np.ix_(rest, rest)], full[rest, z])
    tolerance = math.sqrt(full[z, z] / free) - 1.0
    assert 0.0 < tolerance < 0.02
    sim.host.enable()
    run(sim, 0.2)
    d.qpos[qadr[2]] += 0.002                                   # plucked
    mujoco.mj_forward(m, d)
    t, x = [], []
    run(sim, 1.5, lambda: (t.append(sim.time), x.append(sim.host.mount.displacement[2])))
    t, x = np.array(t), np.array(x)
    k0 = np.flatnonzero(np.sign(x[1:]) != np.sign(x[:-1]))
    crossings = t[k0] - x[k0] * (t[k0 + 1] - t[k0]) / (x[k0 + 1] - x[k0])
    assert len(crossings) >= 8
    measured = math.pi / float(np.mean(np.diff(crossings)))
    assert abs(measured / predicted - 1.0) < tolerance, (measured, predicted, tolerance)
    # a free vibration decaying as e^(-ζ ω t): its largest swing over the last 0.2 s (a
    # peak or more) within the envelope from 0.1 s before that window to 0.1 s after it
    late = t - t[0] >= 1.3
    rate = zeta * predicted / math.sqrt(1.0 - zeta ** 2)
    assert 0.002 * math.exp(-rate * 1.6) < np.abs(x[late]).max() \
        < 0.002 * math.exp(-rate * 1.2)


def test_passive_mount_settles_at_the_deflection_of_the_arms_weight_moment():
    """On rail_arm (the mount carries rail and arm), joint1 turned: the static deflection
    after lifting the arm is K⁻¹ x the change of the weight's wrench at the root, from the
    centre of mass alone (the description's, and MuJoCo's two fingers at tool0): the force
    in the host's axes (the mount's slides), the moment with gravity in the root's true,
    deflected axes (its hinges turn with it: the 4 mrad tilt of a centre of mass 9 cm above
    the pivot adds m g h θ, 2 % of the springs' moment); base_link (host_pose) shows it."""
    desc = load_description(None, "rail_arm")
    spec = HostMotionSpec(name="mount", ramp=0.5, mount=MountSpec(
        mass=0.5, inertia=(0.002,) * 3, stiffness=(1200.0,) * 3 + (150.0,) * 3,
        damping=(60.0,) * 3 + (8.0,) * 3))                     # well damped: settles fast
    q = np.zeros(9)
    q[0] = 0.8                                                # joint1 turned: off the x axis
    # at rest there from the start (the mount is live and preloaded from its attachment)
    sim = hosted(desc, spec, initial={"joint1": q[0]}, block=None)
    model = build_model(desc)
    data = model.createData()

    def weight_wrench() -> np.ndarray:
        """The robot's and the mount body's weight at the root, in its axes (from the COM)."""
        ph = sim.physics
        g_host = sim.host.root_pose()[:3, :3].T @ GRAVITY
        g = ph.body_pose(ph.body["mount"])[:3, :3].T @ GRAVITY
        qk = sim.physics.q[:sim.nk]
        com = pin.centerOfMass(model, data, qk)
        pin.framesForwardKinematics(model, data, qk)
        arm_mass = sum(i.mass for i in model.inertias)
        fingers = 2 * FINGER_MASS
        com = (arm_mass * com + fingers * data.oMf[sim.tool_id].translation) \
            / (arm_mass + fingers)
        mass = arm_mass + fingers
        return np.r_[(mass + 0.5) * g_host, np.cross(com, mass * g)]

    sim.command(ARM, q.tolist())
    sim.host.enable()
    run(sim, 0.6, dt=0.01)
    before = weight_wrench()
    assert np.abs(sim.host.mount.displacement).max() < 1e-9   # preloaded: no sag
    q[1] = -0.6                                               # lift the stretched arm
    sim.command(ARM, q.tolist())
    run(sim, 5.0, dt=0.01)          # the arm swings on its servos (damping ratio < 0.1)
    d = sim.host.mount.displacement
    expected = (weight_wrench() - before) / np.array(spec.mount.stiffness)
    assert abs(expected[3]) > 0.003 and abs(expected[4]) > 0.003   # roll and pitch (rad)
    assert np.abs(d - expected).max() < 0.02 * np.abs(expected).max(), (d, expected)
    assert np.abs(sim.host.mount.velocity).max() < 1e-3        # settled
    # base_link (on the carriage, 5 cm up, where the rail's servo holds it) moved by the
    # mount's translation and turned by its rotation, in world
    host = sim.host.root_pose()
    rot = host[:3, :3].T @ sim.host.base_pose[:3, :3]
    assert np.allclose(pin.log3(rot), d[3:], rtol=0.0, atol=1e-5)
    base = np.array(desc.rail.axis) * sim.physics.q[0] + np.array(desc.rail.mount_xyz)
    assert np.allclose(sim.host.base_pose[:3, 3], host[:3, :3] @ (d[:3] + rot @ base)
                       + host[:3, 3], rtol=0.0, atol=1e-12)


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
