"""Core tier: the simulated work cell with the simulated arm, on MuJoCo: grasp/release/drop
by the pads' friction, contact with the destination peg (the servos' compliance: expected
force and joint efforts), insertion only when aligned within the clearance. No ROS."""
from __future__ import annotations

import copy
import dataclasses
import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.mjcf import FINGER_MASS, finger_travel
from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.mock.scenario import Scenario
from hyperarm_driver.mock.world import BlockState

pytestmark = pytest.mark.core

OPEN, GRIP = 1.3, 0.6      # rad, N·m
DT = 0.01                  # s per simulation call (MuJoCo steps at 1 ms inside)
MAX_PENETRATION = 0.001    # m, issue 23's invariant (test_mock_mujoco)
SLIP = 5e-4                # m the block may move in the grasp and still be "held where it
                           # was" (test_mock_mujoco's slip criterion)
REST = 5e-5                # m: a block resting on the table sinks < 1 µm into MuJoCo's soft
                           # contact under its weight; its centre within this of seated
CORNER = math.cos(math.pi / 12.0)  # a round peg fits the 12-gon hole up to clearance/CORNER
                                   # off its axis (test_mock_tilt)


@pytest.fixture(scope="module")
def desc():
    return load_description()


@pytest.fixture(scope="module")
def cfg():
    c = load_mock_config()   # ideal servos here: the current model has its own tests
    return dataclasses.replace(c, imperfections=dataclasses.replace(
        c.imperfections, repeatability=0.0, seed=1),
        current=dataclasses.replace(c.current, enabled=False))


def sites(cfg):
    w = cfg.world
    half = w.block.size[2] / 2.0
    src, dst = w.peg("source"), w.peg("destination")
    return {
        "src_block": np.array([*src.xy, w.table_height + half]),
        "src_above": np.array([*src.xy, w.table_height + src.height + half + 0.02]),
        "dst_above": np.array([*dst.xy, w.table_height + dst.height + half + 0.02]),
        "dst_base": np.array([*dst.xy, w.table_height + half]),
        "dst_top": w.table_height + dst.height,
        "half": half,
    }


def in_grasp(sim) -> np.ndarray:
    """The block's pose in tool0's frame (where the pads hold it)."""
    return np.linalg.inv(sim.tool_pose()) @ sim.world.block_pose()


def coulomb_grip(desc, cfg) -> float:
    """Gripper torque (N·m) under which the pads' friction no longer carries the block:
    m·g·finger_travel/μ (docs/mujoco.md, test_mock_mujoco)."""
    return cfg.world.block.mass * 9.81 * finger_travel(desc) / cfg.world.friction


def rims_off(sim, peg: str) -> float:
    """The farther of the hole's two rims from peg ``peg``'s axis (m)."""
    return max(sim.world.rim_offsets(peg, sim.world.block_pose()))


class Deepest:
    """The deepest MuJoCo contact after every step of ``sim``."""

    def __init__(self, sim) -> None:
        self.worst = 0.0
        step = sim.step

        def watched(dt: float) -> None:
            step(dt)
            self.worst = max(self.worst, sim.penetration)
        sim.step = watched


def picked(desc, cfg) -> tuple[Scenario, dict]:
    """The block grasped on the source peg and lifted above it; ``sc.grasped`` is the
    block's pose in the grasp as the pads closed."""
    sim = JointSim(desc, cfg)
    sc, s = Scenario(sim, DT), sites(cfg)
    sim.command([desc.gripper.name], [OPEN])         # opening on the way
    sc.move_tool(s["src_above"], 1.2)
    sc.move_tool(s["src_block"], 1.0)
    assert sim.world.state is BlockState.ON_PEG
    sc.grip(0.0, GRIP, seconds=0.6)
    assert sim.world.state is BlockState.HELD
    sc.grasped = in_grasp(sim)
    sc.move_tool(s["src_above"], 1.0)
    return sc, s


def block_energy(sim) -> tuple[float, float]:
    """The free block's kinetic energy (J) and its centre of mass's height (m)."""
    m, d = sim.physics.model, sim.physics.data
    b = sim.physics.block_body
    v = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, b, v, 0)   # [ω; v] at the CoM
    r = d.ximat[b].reshape(3, 3)
    inertia = r @ np.diag(m.body_inertia[b]) @ r.T
    kinetic = 0.5 * m.body_mass[b] * float(v[3:] @ v[3:]) + 0.5 * float(v[:3] @ inertia @ v[:3])
    return kinetic, float(d.xipos[b][2])


def stored_energy(sim) -> float:
    """Elastic energy (J) MuJoCo's soft contacts of the block hold (½ |f| depth each): all
    that a let-go may give the block besides its fall."""
    return sum(0.5 * float(np.linalg.norm(c.force)) * max(0.0, -c.dist)
               for c in sim.physics.contacts(everything=True)
               if c.a.startswith("block_piece") or c.b.startswith("block_piece"))


def let_go(sc, seconds: float) -> float:
    """Open the gripper and simulate ``seconds``; returns by how much (J) the block's kinetic
    energy ever exceeded the potential energy it lost since, less the contacts' stored
    energy at the let-go: <= 0 unless something flung it."""
    sim = sc.sim
    mass = sim.physics.model.body_mass[sim.physics.block_body]
    stored = stored_energy(sim)
    _, z0 = block_energy(sim)
    worst = -math.inf
    sim.command([sim.desc.gripper.name], [OPEN])
    for _ in range(int(round(seconds / 0.002))):
        sim.step(0.002)
        kinetic, z = block_energy(sim)
        worst = max(worst, kinetic - mass * 9.81 * (z0 - z))
    return worst - stored


def test_grasp_lift_insert_aligned_and_release(desc, cfg):
    sc, s = picked(desc, cfg)
    sim = sc.sim
    kinds = [e.kind for e in sim.take_events()]
    assert kinds == ["grasped", "unthreaded"]
    assert sim.effort[-1] == pytest.approx(-GRIP)              # closing at the current limit
    # carried by the tool: where the pads took it (MuJoCo's friction grasp, no weld)
    assert in_grasp(sim)[:3, 3] == pytest.approx(sc.grasped[:3, 3], abs=SLIP)
    sc.move_tool(s["dst_above"], 2.0)
    sc.move_tool(s["dst_base"], 2.0)      # straight down: aligned, slides down the peg
    assert [e.kind for e in sim.take_events()] == ["threaded"]
    clearance = cfg.world.clearance("destination")
    assert rims_off(sim, "destination") <= clearance / CORNER + sim.penetration
    assert sim.contact_force[2] > 0.0                         # down on the table
    assert sim.penetration < MAX_PENETRATION
    sc.grip(OPEN, seconds=0.8)
    assert [e.kind for e in sim.take_events()] == ["released"]
    assert sim.world.on_peg("destination")
    rest = sim.world.block_pose()
    assert rest[2, 3] == pytest.approx(s["dst_base"][2], abs=REST)
    assert rims_off(sim, "destination") <= clearance / CORNER + sim.penetration


def test_misaligned_block_stops_on_peg_top_with_expected_force_and_efforts(desc, cfg):
    """Pressing the block 5 mm into the top of the peg, misaligned: the peg pushes back (up,
    inside the friction cone, no deeper than MuJoCo's invariant), the servos yield by
    torque/stiffness (K⁻¹ Jᵀ F from the contact wrench MuJoCo reports at tool0), and their
    efforts balance gravity (the arm, the fingers, the held block) and the contact force.
    Let go there, the block stays on the top or tips off beside the peg, neither threaded
    nor flung."""
    sc, s = picked(desc, cfg)
    sim = sc.sim
    deep = Deepest(sim)
    clearance = cfg.world.clearance("destination")
    off = np.array([2.5 * clearance, 0.0, 0.0])
    sc.move_tool(s["dst_above"] + off, 2.0)
    press = s["dst_above"] + off
    press[2] = s["dst_top"] + s["half"] - 0.005               # 5 mm below the peg top
    q_cmd = sc.move_tool(press, 2.0)
    force = sim.contact_force
    assert sim.world.peg is None and sim.world.state is BlockState.HELD
    assert force[2] > 0.5                                     # N, the peg pushes up
    assert np.linalg.norm(force[:2]) <= cfg.world.friction * force[2] * (1 + 1e-9)
    assert deep.worst < MAX_PENETRATION
    bottom = sim.world.block_pose()[2, 3] - s["half"]
    assert bottom > s["dst_top"] - MAX_PENETRATION            # on the top, not through it
    # Servo springs: the joints are deflected by K^-1 J^T F from their goals...
    model, data, fid = sim.model, sim.model.createData(), sim.tool_id
    q_meas = sim.position[:9] + sim.offset[:9]
    pin.framesForwardKinematics(model, data, q_meas)
    local = pin.computeFrameJacobian(model, data, q_meas, fid, pin.ReferenceFrame.LOCAL)
    generalized = local.T @ sim.tool_wrench                   # tool_wrench: at tool0, its axes
    assert np.abs(generalized).max() > 0.05                   # N·m: a real load on the joints
    tol = 0.02 * np.abs(generalized).max()
    assert (q_meas - q_cmd) * cfg.servo.stiffness == pytest.approx(generalized, abs=tol)
    # ...and their efforts hold gravity and push back against the peg: the arm's weight,
    # the two fingers' (at tool0) and the held block's (at its centre), minus the contact's
    aligned = pin.computeFrameJacobian(model, data, q_meas, fid,
                                       pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    lever = sim.world.block_pose()[:3, 3] - data.oMf[fid].translation
    gravity = pin.computeGeneralizedGravity(model, data, q_meas) \
        + aligned[:3].T @ [0.0, 0.0, 2 * FINGER_MASS * 9.81] \
        + (aligned[:3] - pin.skew(lever) @ aligned[3:]).T @ [0.0, 0.0,
                                                              cfg.world.block.mass * 9.81]
    assert sim.effort[:9] == pytest.approx(gravity - generalized, abs=tol)
    # Let go here: the hole over the peg's edge, its centre of mass is over no support
    # (the peg's top meets the block only on a crescent beside the hole): it tips, and may
    # rest on the top or leaning on the peg, or fall beside it; never down the peg, never
    # faster than its fall makes it (before, a teleport rule put it back on the top).
    excess = let_go(sc, 0.8)
    assert excess <= 0.0, excess
    assert sim.world.state in (BlockState.ON_PEG_TOP, BlockState.ON_TABLE)
    assert not sim.world.on_peg("destination")


def _place_over(sc, xyz, seconds: float) -> None:
    """Move the held block (not the tool) to ``xyz``: the tool where the grasp puts the
    block there (twice, the second from where the first left it)."""
    for _ in range(2):
        sc.move_tool(sc.tool_target + (xyz - sc.block_xyz()), seconds / 2.0)


def test_insertion_succeeds_once_aligned_within_clearance(desc, cfg):
    """The block (where it really is in the grasp) brought over the peg 2 and 1.3 x the
    clearance off its axis (+x: the arm's spring, pressed, pushes it further off) and
    pressed 5 mm below the top: it stays on the top; 0.7 x the clearance off it goes down
    the peg freely (no contact force), carried by the tool."""
    sc, s = picked(desc, cfg)
    sim = sc.sim
    clearance = cfg.world.clearance("destination")
    above = s["dst_above"].copy()
    sc.move_tool(above, 2.0)
    for dx in (2.0 * clearance, 1.3 * clearance):             # misaligned: stays on top
        _place_over(sc, above + [dx, 0.0, 0.0], 1.0)
        assert rims_off(sim, "destination") > clearance / CORNER
        sc.move_tool(sc.tool_target - [0.0, 0.0, 0.025], 1.0)
        assert sim.world.peg is None and sim.contact_force[2] > 0.0
        assert sc.block_xyz()[2] - s["half"] > s["dst_top"] - MAX_PENETRATION
        assert sim.penetration < MAX_PENETRATION
        sc.move_tool(sc.tool_target + [0.0, 0.0, 0.025], 1.0)
    _place_over(sc, above + [0.7 * clearance, 0.0, 0.0], 1.0)  # within the clearance
    grasp = in_grasp(sim)
    sc.move_tool(sc.tool_target - [0.0, 0.0, 0.025], 1.0)
    assert sim.world.peg == "destination"
    assert np.linalg.norm(sim.contact_force) < 1e-6          # N: slid down, no force
    assert in_grasp(sim)[:3, 3] == pytest.approx(grasp[:3, 3], abs=SLIP)
    assert sc.block_xyz()[2] - s["half"] < s["dst_top"] - 0.004
    sc.move_tool(s["dst_base"], 2.0)
    sc.grip(OPEN, seconds=0.8)
    assert sim.world.on_peg("destination")


def test_current_limit_bounds_the_pressing_force(desc, cfg):
    """Current-based position: a servo's actuator force is clamped to its limit, so the
    arm pushes on the peg with at most what its limits give. Pressed 1 cm into the peg's
    top, 6 mm off its axis, with each arm servo's limit 0.1 N·m above its hovering effort:
    in position mode some servo exceeds that limit during the press; current-limited, no
    servo ever does (after every step), some yield at it, and the block stays on the top,
    neither press going through it. (Pressing down relieves the joints holding the arm's
    weight, so the limits bind at the wrist, whose yield turns the block in the pads: the
    contact force in N is not lower for it, the joints' torques are bounded; the pads'
    friction, not the servos, bounds the force of deeper presses: the block slides up
    between them.)"""
    sc0, s = picked(desc, cfg)
    press = s["dst_above"] + [0.006, 0.0, 0.0]
    sc0.move_tool(press, 1.5)
    limit = np.abs(sc0.sim.effort[:9]) + 0.1                 # hovering + 0.1 N·m
    press = press - [0.0, 0.0, 0.03]                          # 1 cm into the peg's top
    peak = {}
    for limited in (False, True):
        sc = copy.deepcopy(sc0)
        sim = sc.sim
        deep = Deepest(sim)
        worst = np.zeros(9)
        step = sim.step

        def watched(dt: float) -> None:
            step(dt)
            worst[:] = np.maximum(worst, np.abs(sim.effort[:9]) - sim.limit[:9])
        sim.step = watched
        sc.move_tool(press, 2.0, effort=limit if limited else None)
        assert sim.world.state is BlockState.HELD and sim.world.peg is None
        assert sim.contact_force[2] > 0.5                     # N: pressing on the top
        assert sc.block_xyz()[2] - s["half"] > s["dst_top"] - MAX_PENETRATION
        assert deep.worst < MAX_PENETRATION
        peak[limited] = np.maximum(worst + sim.limit[:9] - limit, 0.0)   # over the limit
        if limited:
            assert sim.limit[:9] == pytest.approx(limit)
            assert np.all(worst <= 1e-9), worst               # the actuator's clamp
            assert np.any(worst >= -1e-9)                     # some servo yields at it
    assert np.any(peak[False] > 0.0)                          # position mode goes beyond


def test_weak_grip_drops_the_block(desc, cfg):
    """The gripper's limit lowered to half the torque whose squeeze carries the block
    (Coulomb: m·g·finger_travel/μ): it slides out of the pads and falls straight down onto
    the table, not flung."""
    sc, s = picked(desc, cfg)
    sim = sc.sim
    mid = np.array([0.35, 0.0, s["src_above"][2]])
    sc.move_tool(mid, 2.0)
    sim.take_events()
    under = sim.world.block_pose()[:2, 3].copy()
    stored = stored_energy(sim)
    mass = sim.physics.model.body_mass[sim.physics.block_body]
    _, z0 = block_energy(sim)
    sim.command([desc.gripper.name], [0.0], [0.5 * coulomb_grip(desc, cfg)])
    worst = -math.inf
    for _ in range(300):
        sim.step(0.002)
        kinetic, z = block_energy(sim)
        worst = max(worst, kinetic - mass * 9.81 * (z0 - z))
    assert [e.kind for e in sim.take_events()] == ["dropped"]
    assert sim.world.state is BlockState.ON_TABLE
    assert worst <= stored                                      # fell, not flung
    rest = sim.world.block_pose()
    assert rest[2, 3] == pytest.approx(cfg.world.table_height + s["half"], abs=REST)
    assert rest[2, 2] == pytest.approx(1.0, abs=1e-6)            # landed flat
    assert np.linalg.norm(rest[:2, 3] - under) < cfg.world.block.size[0] / 2.0


def test_position_only_close_grips_with_grip_effort_like_the_driver(desc, cfg):
    """The Dynamixel driver's rule (docs/dynamixel.md): a position-only gripper command runs
    current-based position with ``gripper.grip_effort`` as its limit; closing, the servo
    reports a negative effort of that size; no overload however long it holds."""
    from hyperarm_driver.mock.joint_sim import OVERLOAD_TIME, ControlMode

    sc, _ = picked(desc, cfg)
    sim = sc.sim
    sim.take_events()
    sc.grip(0.0, seconds=0.5)                        # position only, goal inside the block
    assert sim.mode[-1] is ControlMode.CURRENT_POSITION
    assert sim.state().effort[-1] == pytest.approx(-desc.gripper.grip_effort)
    sc.run(OVERLOAD_TIME + 0.5)
    assert not sim.errors and sim.world.state is BlockState.HELD


def test_stall_torque_grip_overloads_and_drops_the_block(desc, cfg):
    """Gripping with the stall torque as the limit, goal deep inside the block, holds the
    servo at its stall torque: after OVERLOAD_TIME it raises an overload error, drops its
    torque and the block, as a Dynamixel does (the block, above its source peg, falls back
    onto it)."""
    from hyperarm_driver.mock.joint_sim import OVERLOAD_TIME

    stiff = dataclasses.replace(cfg, servo=dataclasses.replace(cfg.servo,
                                                               gripper_stiffness=20.0))
    sc, _ = picked(desc, stiff)                      # grasped with the grip torque: fine
    sim = sc.sim
    sim.take_events()
    sc.grip(0.0, effort=sim.stall[-1], seconds=0.5)
    assert sim.world.state is BlockState.HELD
    assert abs(sim.effort[-1]) == pytest.approx(sim.stall[-1])   # at its stall torque
    sc.run(OVERLOAD_TIME - 0.5 - 0.1)
    assert not sim.errors and sim.world.state is BlockState.HELD
    sc.run(0.2)
    assert sim.errors == {"gripper": "overload"}
    kinds = [e.kind for e in sim.take_events()]
    assert kinds[:2] == ["hardware_error", "dropped"] and set(kinds[2:]) <= {"landed"}, kinds
    assert sim.world.state is not BlockState.HELD


def test_no_grasp_when_too_weak_or_nothing_between_fingers(desc, cfg):
    sim = JointSim(desc, cfg)
    sc, s = Scenario(sim, DT), sites(cfg)
    sc.grip(OPEN, seconds=0.8)
    sc.grip(0.0, GRIP, seconds=1.0)       # nothing between the fingers: closes fully
    # the pads meet: the fingers at the end of their range, to the softness of MuJoCo's
    # limit and coupling constraints under the squeeze (26 µm at 0.6 N·m)
    assert 2.0 * finger_travel(desc) * sim.position[-1] < 1e-4
    assert sim.world.state is BlockState.ON_PEG and sim.take_events() == []
    sc.grip(OPEN, seconds=0.8)
    sc.move_tool(s["src_above"], 2.0)
    sc.move_tool(s["src_block"], 1.5)
    sc.grip(0.75, seconds=0.5)            # just short of the block (it fills 0.70 rad)
    sc.grip(0.0, 0.5 * coulomb_grip(desc, cfg), seconds=0.8)   # too weak to carry it
    sc.move_tool(s["src_above"], 1.0)
    assert sim.world.on_peg("source")     # left on its peg, down at the table
    assert sim.world.block_pose()[2, 3] == pytest.approx(s["src_block"][2], abs=REST)


def test_blind_descent_usually_fails_and_dither_inserts(desc):
    """The paper's situation with the default work cell (repeatability on): the block
    picked, then brought over the destination peg in a new move (a joint-space jump: its
    own repeatability offset; the pads take the block where it stands, so the grasp's
    offset no longer carries over), pushing it straight down mostly stops on the peg's top,
    while backing up and pressing and dithering in x-y over a growing spiral (radius up to
    1.5 cm, 6 turns: slow enough for the block to drop in as the hole passes the peg, as
    insertion_mc's) inserts it."""
    base = load_mock_config()
    blind, dithered = [], []
    for seed in range(4):
        cfg = dataclasses.replace(base, imperfections=dataclasses.replace(
            base.imperfections, seed=seed))
        sc, s = picked(desc, cfg)
        sim = sc.sim
        sc.tool_target = None                                # a joint-space move: new draw
        sc.move_tool(s["dst_above"], 1.5)
        press = s["dst_above"].copy()
        press[2] = s["dst_top"] + s["half"] - 0.005          # 5 mm below the top
        sc.move_tool(press, 1.5)
        blind.append(sim.world.peg == "destination")
        if not blind[-1]:                                    # back up (slid off the edge?)
            sc.move_tool(s["dst_above"], 1.0)                # and down again, streamed:
            sc.move_tool(press, 1.0)                         # the same move, its offset
        for k in range(400):
            if sim.world.peg == "destination":
                break
            r, a = 0.015 * k / 400, 2.0 * np.pi * 6.0 * k / 400
            sc.move_tool(press + [r * np.cos(a), r * np.sin(a), 0.0], 0.02)
        dithered.append(sim.world.peg == "destination")
        sc.move_tool(s["dst_base"], 1.0)
        sc.grip(OPEN, seconds=0.4)
        assert sim.world.on_peg("destination") == dithered[-1]
    assert sum(blind) <= 1, blind
    assert all(dithered), dithered
