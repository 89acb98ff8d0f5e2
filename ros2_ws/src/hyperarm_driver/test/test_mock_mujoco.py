"""Core tier: the simulated robot on MuJoCo (``mock/mujoco_sim.py``, issue 23): the servos'
firmware models on MuJoCo's actuators, a physical grasp, ground truth from MuJoCo's contacts.

Checked on the physics, not on our reading of it: the block transfer by friction alone,
the slip threshold against Coulomb's law, penetration over random commands, creep at rest,
the servo modes as MuJoCo's actuator parameters, efforts against pinocchio's gravity.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.mjcf import FINGER_MASS, finger_travel
from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import ControlMode
from hyperarm_driver.mock.joint_sim import JointSim as MujocoSim
from hyperarm_driver.mock.scenario import Scenario, self_contacts, tool_down_ik
from hyperarm_driver.mock.world import BlockState

pytestmark = [pytest.mark.core]

DT = 0.01
MAX_PENETRATION = 0.001   # m, issue 23's invariant


def _cfg(ideal_current: bool = False, seed: int = 5):
    c = load_mock_config()
    c = dataclasses.replace(c, imperfections=dataclasses.replace(c.imperfections,
                                                                 repeatability=0.0, seed=seed))
    if ideal_current:
        c = dataclasses.replace(c, current=dataclasses.replace(c.current, enabled=False))
    return c


class _Deepest:
    """The deepest MuJoCo contact after every step of ``sim``."""

    def __init__(self, sim: MujocoSim) -> None:
        self.worst = 0.0
        step = sim.step

        def watched(dt: float) -> None:
            step(dt)
            self.worst = max(self.worst, sim.penetration)
        sim.step = watched


def _pick(sim: MujocoSim, sc: Scenario, effort: float = 0.6) -> np.ndarray:
    w = sim.cfg.world
    src, half = w.peg("source"), w.block.size[2] / 2.0
    block = np.array([*src.xy, w.table_height + half])
    sc.grip(1.2, seconds=0.5)
    sc.move_tool(block + [0, 0, 0.12], 1.5)
    sc.move_tool(block, 1.0)
    sc.grip(0.0, effort, seconds=0.5)
    sc.move_tool(block + [0, 0, 0.12], 1.0)
    return block


def test_the_block_transfer_runs_on_friction_alone():
    """Grasped by the pads' friction (no weld, no capture radius), lifted off the source
    peg, threaded onto the destination and let go: it slides down to the peg's base; no
    contact ever penetrates 1 mm."""
    sim = MujocoSim(load_description(), _cfg())
    deep = _Deepest(sim)
    sc = Scenario(sim, DT)
    w = sim.cfg.world
    _pick(sim, sc)
    assert sim.world.state is BlockState.HELD
    dst, half = w.peg("destination"), w.block.size[2] / 2.0
    above = np.array([*dst.xy, w.table_height + dst.height + half + 0.02])
    sc.move_tool(above, 2.0)
    sc.move_tool(above - [0, 0, 0.05], 2.0)
    assert sim.world.state is BlockState.HELD and sim.world.peg == "destination"
    sc.grip(1.2, seconds=1.0)
    sc.move_tool(above + [0, 0, 0.05], 1.0)
    sc.run(1.0)
    kinds = [e.kind for e in sim.take_events()]
    assert kinds[:4] == ["grasped", "unthreaded", "threaded", "released"], kinds
    assert sim.world.on_peg("destination")
    bottom = sim.world.block_pose()[2, 3] - half
    assert bottom == pytest.approx(w.table_height, abs=1e-3)   # down at the peg's base
    assert deep.worst < MAX_PENETRATION


def test_a_weak_grip_slips_within_20_percent_of_coulombs_prediction():
    """Lowering the gripper's current limit step by step under the lifted block: it starts
    to slide out at the torque where the two pads' friction, 2 μ N with N = τ / (2 ·
    finger travel), no longer carries its weight."""
    desc = load_description()
    sim = MujocoSim(desc, _cfg(ideal_current=True))
    sc = Scenario(sim, DT)
    _pick(sim, sc, effort=0.3)
    sc.run(0.5)
    assert sim.world.state is BlockState.HELD
    w = sim.cfg.world
    predicted = w.block.mass * 9.81 * finger_travel(desc) / w.friction
    g = desc.gripper.name
    rel = sim.world.block_pose()[2, 3] - sim.tool_pose()[2, 3]
    slipped_at = None
    for tau in np.arange(0.3, 0.0, -0.002):
        sim.command([g], [0.0], [float(tau)])
        sc.run(0.2)
        now = sim.world.block_pose()[2, 3] - sim.tool_pose()[2, 3]
        if abs(now - rel) > 5e-4 or sim.world.state is not BlockState.HELD:
            slipped_at = float(sim.limit[sim.g])
            break
        rel = now
    assert slipped_at is not None, "the block never slipped"
    assert abs(slipped_at - predicted) <= 0.2 * predicted, (slipped_at, predicted)


def test_servo_modes_are_mujocos_actuator_parameters():
    """Position class: a PD within the true current limit; current: a motor whose force is
    its control (the servo model keeps it on the torque-speed line); off (and a mode
    switch's gap): no force. Set at run time on the same model."""
    desc = load_description()
    sim = MujocoSim(desc, _cfg())
    ph, m = sim.physics, sim.physics.model
    a = ph._act[0]
    assert m.actuator_gainprm[a, 0] == pytest.approx(sim.cfg.servo.stiffness)
    assert m.actuator_forcerange[a, 1] == pytest.approx(sim.limit[0])
    sim.command(["joint1"], [0.1], [1.5])
    sim.step(DT)
    assert sim.mode[0] is ControlMode.CURRENT_POSITION
    assert m.actuator_forcerange[a, 1] == pytest.approx(sim.limit[0])
    assert sim.limit[0] == pytest.approx(sim.kt_ratio[0] * 1.5, rel=1e-2)
    sim.command(["joint1"], efforts=[0.5])
    sim.step(0.002)                          # inside the mode switch's gap: no force
    assert m.actuator_forcerange[a, 1] == 0.0
    sim.step(DT)
    assert sim.mode[0] is ControlMode.TORQUE
    assert m.actuator_gainprm[a, 0] == 1.0
    assert m.actuator_biasprm[a, 2] == 0.0    # no damping: the current loop holds its goal
    sim.set_torque(False, ["joint1"])
    sim.step(DT)
    assert tuple(m.actuator_forcerange[a]) == (0.0, 0.0)
    assert m.nu == sim.n                     # nothing was added: the same model


def _free_posture(desc, cfg, seed: int) -> MujocoSim:
    """A simulation at rest in a random posture where no link, pad or the block touches
    anything but what it rests on (the block on its peg)."""
    rng = np.random.default_rng(seed)
    for _ in range(200):
        q = rng.uniform(-1.0, 1.0, 9)
        sim = MujocoSim(desc, cfg, initial={f"joint{i + 1}": float(v) for i, v in enumerate(q)})
        touching = [c for c in sim.physics.contacts(everything=True)
                    if not {c.a[:11], c.b[:11]} <= {"block_piece", "table", "peg_source"}]
        if not touching:
            return sim
    raise AssertionError("no free posture drawn")


def test_torque_off_the_arm_sags_under_gravity():
    sim = _free_posture(load_description(), _cfg(), 7)
    q0 = sim.position.copy()
    for _ in range(50):
        sim.step(DT)
    assert np.max(np.abs(sim.position - q0)) < 2e-3     # torque on: held (friction's band)
    sim.set_torque(False)
    for _ in range(50):
        sim.step(DT)
    assert np.max(np.abs(sim.position[:sim.nk] - q0[:sim.nk])) > 0.05


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_held_efforts_are_the_gravity_load(seed):
    """At rest in a random posture touching nothing, each arm servo's actuator exerts the
    gravity torque pinocchio computes from the description (to the Coulomb friction the
    servo may leave to the joint's static friction)."""
    desc = load_description()
    sim = _free_posture(desc, _cfg(ideal_current=True), seed)
    for _ in range(100):
        sim.step(DT)
    model = sim.model
    data = model.createData()
    q = sim.position[:sim.nk] + sim.offset[:sim.nk]
    g = pin.computeGeneralizedGravity(model, data, q)
    # the MuJoCo model's two fingers (not in the description's chain) hang at tool0
    jac = pin.computeFrameJacobian(model, data, q, sim.tool_id,
                                   pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    g += jac.T @ np.array([0.0, 0.0, 2 * FINGER_MASS * 9.81])
    assert np.allclose(sim.effort[:sim.nk], g, rtol=0.01, atol=2e-3), (sim.effort[:sim.nk], g)


def test_the_arm_at_rest_creeps_less_than_0_1_mm_per_minute():
    sim = MujocoSim(load_description(), _cfg())
    sc = Scenario(sim, DT)
    w = sim.cfg.world
    sc.move_tool([0.3, 0.0, w.table_height + 0.15], 1.5)
    sc.run(3.0)                                 # come to rest
    start = sim.tool_pose()[:3, 3].copy()
    sc.run(30.0)
    creep = float(np.linalg.norm(sim.tool_pose()[:3, 3] - start))
    assert creep < 0.1e-3 / 2.0, creep        # over half a minute


@pytest.mark.parametrize("seed", [11, 12])
def test_random_mixed_commands_never_penetrate_1_mm(seed):
    """Random goals within the joint limits (position, current-limited, torque, torque
    off and on, the gripper): the deepest MuJoCo contact stays under 1 mm."""
    desc = load_description()
    sim = MujocoSim(desc, _cfg(seed=seed))
    deep = _Deepest(sim)
    rng = np.random.default_rng(seed)
    names = sim.names
    for _ in range(25):
        kind = rng.integers(0, 5)
        if kind == 0:
            sim.command(names, rng.uniform(sim.lower, sim.upper).tolist())
        elif kind == 1:
            sim.command(names, rng.uniform(sim.lower, sim.upper).tolist(),
                        rng.uniform(0.2, 1.0, sim.n).tolist())
        elif kind == 2:
            sim.command(names[:sim.nk], efforts=rng.uniform(-0.5, 0.5, sim.nk).tolist())
        elif kind == 3:
            sim.set_torque(False, list(rng.choice(names, 3, replace=False)))
        else:
            sim.set_torque(True)
        for _ in range(int(rng.integers(10, 60))):
            sim.step(DT)
    assert deep.worst < MAX_PENETRATION, deep.worst
