"""Core tier: physical invariants of insertion (issue 9, item 2), as properties over drawn
commands (hypothesis), on the ROS-free simulation core (MuJoCo).

- a misaligned block pressed down to any depth (even below the table), in position mode or
  current-limited, penetrates nothing by more than 2 mm after any step (MuJoCo's deepest
  contact, every contact counted), and it is never flung: it moves at most as fast as the
  arm's joints can move it; settled, the limited joints exert at most their limits (and
  their friction) against the contact;
- torque (effort-only) presses neither fling the block nor push it more than 2 mm in;
- a block let go threaded rests within the clearance of the peg's axis; let go on the top
  (its hole over the peg's edge), it stays on the top or tips off beside the peg, not
  flung and not down the peg;
- the repeatability offset is drawn once per move: streamed small setpoints (an approach, a
  press, a dither) keep it; a jump of the goals draws a new one.
"""
from __future__ import annotations

import copy
import dataclasses
import math

import mujoco
import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st
import pinocchio as pin

from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.mock.scenario import Scenario
from hyperarm_driver.mock.servos import OFFSET_RATE
from hyperarm_driver.mock.world import BlockState

pytestmark = [pytest.mark.core, pytest.mark.slow]

DT = 0.01
MAX_PENETRATION = 0.002   # m, issue 9 item 2
NO_SHRINK = (Phase.explicit, Phase.reuse, Phase.generate)   # a known failure: no minutes
CORNER = math.cos(math.pi / 12.0)  # a round peg fits the 12-gon hole up to clearance/CORNER
                                   # off its axis (test_mock_tilt)


def _cfg(repeatability: float = 0.0):
    c = load_mock_config()
    return dataclasses.replace(c, imperfections=dataclasses.replace(
        c.imperfections, repeatability=repeatability, seed=5))


@pytest.fixture(scope="module")
def held():
    """The block grasped on the source peg, lifted and brought above the destination."""
    cfg = _cfg()
    sim = JointSim(load_description(), cfg)
    sc = Scenario(sim, DT)
    w = cfg.world
    src, dst, half = w.peg("source"), w.peg("destination"), w.block.size[2] / 2.0
    block = np.array([*src.xy, w.table_height + half])
    sim.command([sim.desc.gripper.name], [1.2])      # opening on the way
    sc.move_tool(block + [0, 0, 0.12], 1.2)
    sc.move_tool(block, 1.0)
    sc.grip(0.0, 0.6, seconds=0.6)
    sc.move_tool(block + [0, 0, 0.12], 1.0)
    above = np.array([*dst.xy, w.table_height + dst.height + half + 0.02])
    sc.move_tool(above, 1.5)
    assert sim.world.state is BlockState.HELD
    return sc, above, half, w.table_height + dst.height


class _Watch:
    """Checks after every simulation step of ``sim``: the deepest MuJoCo contact (any two
    bodies: the held block in the table, a peg or its wall, a link in a peg, the pads in
    the block), and the block's largest step against what the arm can do: the block's
    displacement over a step divided by the bound dt·Σ_i |∂p/∂q_i|·vmax_i (every joint at
    its velocity limit, at the true joints)."""

    def __init__(self, sim) -> None:
        self.sim, self.data = sim, sim.model.createData()
        self.penetration, self.speed = 0.0, 0.0
        self.last = self._block()
        step = sim.step

        def checked(dt):
            step(dt)
            self.penetration = max(self.penetration, sim.penetration)
            b = self._block()
            if b is not None and self.last is not None:
                self.speed = max(self.speed, float(np.linalg.norm(b - self.last))
                                 / (dt * self._bound()))
            self.last = b

        sim.step = checked

    def _block(self):
        s = self.sim
        return s.world.block_pose()[:3, 3].copy() \
            if s.world.state is BlockState.HELD else None

    def _bound(self) -> float:
        s, nk = self.sim, self.sim.nk
        q = s.position[:nk] + s.offset[:nk]
        j = pin.computeFrameJacobian(s.model, self.data, q, s.tool_id,
                                     pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        r = self.last - s.tool_pose()[:3, 3]
        jp = j[:3] + np.cross(j[3:].T, r).T          # the block centre's linear Jacobian
        return float(np.linalg.norm(jp, axis=0) @ s.vmax[:nk])


def _load(sim) -> np.ndarray:
    """Each arm joint's load (N·m) from MuJoCo's state: gravity and velocity products of
    the arm (qfrc_bias) less Jᵀ f of every contact the robot's bodies get from outside it
    (the block through the pads, the table or a peg on a pad or a link): what its servo and
    its own friction must exert, at rest."""
    ph = sim.physics
    m, d = ph.model, ph.data
    dofs = [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]
            for n in sim.names[:sim.nk]]
    outside = {0, ph.block_body}                        # the world (the cell) and the block
    jac = np.zeros((3, m.nv))
    load = d.qfrc_bias[dofs].copy()
    for c in ph.contacts(everything=True):
        for geom, force in ((c.a, c.force), (c.b, -c.force)):    # force: b's on a
            body = int(m.geom_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, geom)])
            other = c.b if geom == c.a else c.a
            if body in outside or int(m.geom_bodyid[mujoco.mj_name2id(
                    m, mujoco.mjtObj.mjOBJ_GEOM, other)]) not in outside:
                continue
            mujoco.mj_jac(m, d, jac, None, c.point, body)
            load -= jac[:, dofs].T @ force
    return load


@settings(max_examples=3, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(off=st.floats(0.003, 0.03), angle=st.floats(0.0, 2.0 * math.pi),
       depth=st.floats(0.0, 0.12), limited=st.booleans())
@example(off=0.005, angle=0.5 * math.pi, depth=0.12, limited=False)   # went through the
@example(off=0.003, angle=math.pi, depth=0.12, limited=False)         # peg (issue 9)
@example(off=0.005, angle=0.5 * math.pi, depth=0.12, limited=True)    # 90 mm in, flung
@example(off=0.005, angle=0.0, depth=0.12, limited=True)              # 79 mm in, 62 m/s
@example(off=0.029259817282555344, angle=3.2379928555727426,          # beside the peg onto
         depth=0.11235258705141944, limited=True)                     # the table, sliding
def test_press_never_penetrates_nor_flings(held, off, angle, depth, limited):
    """Issue 9 item 2, after every simulation step: a misaligned block pressed down to any
    depth (4 cm under the table at most), in position mode or current-limited (current-
    based position, a limit just above each joint's load), penetrates nothing by more than
    2 mm (whether it stays on the top, slides over the hole and threads, or slides off the
    top and comes down beside the peg), and is never flung: it moves at most as fast as the
    arm can move it. Settled, each current-limited joint exerts at most its limit against
    the contact (its own Coulomb friction may hold the rest): the contact's generalized
    force is what the limited joints can give. (The last example, once drawn, came down on
    the table beside the peg sliding at its friction cone.)"""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    d = np.array([off * math.cos(angle), off * math.sin(angle), 0.0])
    sc.move_tool(above + d, 0.6)
    target = above + d
    target[2] = top + half - depth
    effort = np.abs(sim.effort[:9]) + 0.5 if limited else None
    watch = _Watch(sim)
    sc.tool_target = above + d
    for k in range(1, 13):
        sc.move_tool(above + d + (target - above - d) * k / 12, 0.15, effort=effort)
    sc.run(0.5)
    assert sim.world.state is BlockState.HELD
    assert watch.penetration <= MAX_PENETRATION, watch.penetration
    assert watch.speed <= 1.0, watch.speed
    # settled: the joints' torques against the contacts within their limits and friction
    # (1e-3 N·m: what is left of the motion)
    nk = sim.nk
    need = _load(sim)
    assert np.all(np.abs(need) <= sim.limit[:nk] + sim.coulomb[:nk] + 1e-3), \
        (need, sim.limit[:nk])


def _torque_press(held, off, angle, force):
    """Above the destination peg, ``off`` m from its axis towards ``angle``, the arm
    switched to torque control (effort-only commands, re-sent every 0.1 s): the holding
    torques plus Jᵀ of a push of ``force`` N down and 0.3 x that sideways, for 2 s."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    d = np.array([off * math.cos(angle), off * math.sin(angle), 0.0])
    sc.move_tool(above + d, 0.6)
    nk = sim.nk
    j = pin.computeFrameJacobian(sim.model, sim.model.createData(), sim.position[:nk],
                                 sim.tool_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    push = force * np.array([0.3 * math.cos(angle + 1.0), 0.3 * math.sin(angle + 1.0), -1.0])
    tau = sim.effort[:nk] + j[:3].T @ push
    watch = _Watch(sim)
    for _ in range(20):
        sim.command(sc.arm, [], tau.tolist())
        sc.run(0.1)
    return sim, watch


@settings(max_examples=4, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(off=st.floats(0.0, 0.03), angle=st.floats(0.0, 2.0 * math.pi),
       force=st.floats(0.0, 30.0))
@example(off=0.00085, angle=0.781, force=19.4)    # 3-13 mm in before the step guard
def test_torque_press_never_flings_nor_penetrates(held, off, angle, force):
    """Effort-only (torque) commands pushing the held block down onto the peg or the table:
    the block moves at most as fast as the arm can move it (before a fix the contact spring
    in the torque-mode dynamics pushed the wrong way: 50-80 m/s), nothing goes more than
    2 mm into anything (a block driven fast onto the table or turned against a peg's side
    once went 3-13 mm in), the states stay finite, it stays held."""
    sim, watch = _torque_press(held, off, angle, force)
    assert sim.world.state is BlockState.HELD
    assert np.all(np.isfinite(sim.position)) and np.all(np.isfinite(sim.velocity))
    assert watch.speed <= 1.0, watch.speed
    assert watch.penetration <= MAX_PENETRATION, watch.penetration


@settings(max_examples=3, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(off=st.floats(0.0, 0.0015), angle=st.floats(0.0, 2.0 * math.pi),
       push=st.floats(0.0, 0.01), push_angle=st.floats(0.0, 2.0 * math.pi))
def test_threaded_block_rests_within_the_clearance(held, off, angle, push, push_angle):
    """The block's hole aligned within the clearance: it threads; pushed sideways (up to
    1 cm of command) at the peg's base and let go, it rests with its hole around the peg:
    both rims within c / cos(π/12) of the axis (the 12-gon hole, test_mock_tilt), deeper
    only by what MuJoCo's contacts penetrate. (Aligned: the block where it really is, which
    is off the tool by the grasp.)"""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    grasp = sc.block_xyz() - above
    d = np.array([off * math.cos(angle) - grasp[0], off * math.sin(angle) - grasp[1], 0.0])
    base = above + d
    base[2] = sim.cfg.world.table_height + half + 0.005
    sc.move_tool(above + d, 0.6)
    sc.move_tool(base, 1.2)
    assert sim.world.peg == "destination"
    p = np.array([push * math.cos(push_angle), push * math.sin(push_angle), 0.0])
    sc.move_tool(base + p, 0.8)
    sc.grip(1.2, seconds=0.6)
    assert sim.world.state is BlockState.ON_PEG
    clearance = sim.cfg.world.clearance("destination")
    rims = sim.world.rim_offsets("destination", sim.world.block_pose())
    assert max(rims) <= clearance / CORNER + sim.penetration, rims


@settings(max_examples=3, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**16))
def test_threaded_block_dragged_by_any_command_stays_out_of_the_wall(held, seed):
    """Threaded on the destination peg, 3 cm down, the block dragged by random joint-space
    commands (jumps of up to ±0.25 rad per joint, each held 0.3 s): nothing goes more than
    2 mm into the hole's wall, the peg or the table (a solve against the plane of the
    wall's normal at the commanded joints once let such drags go 1-3.6 cm in): the arm
    jams instead, its servos at their limits."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    grasp = sc.block_xyz() - above
    down = above - [grasp[0], grasp[1], 0.0]
    sc.move_tool(down, 0.6)
    sc.move_tool(down - [0.0, 0.0, 0.05], 1.2)
    assert sim.world.peg == "destination"
    watch = _Watch(sim)
    rng = np.random.default_rng(seed)
    q0 = sim.goal[:9].copy()
    for _ in range(8):
        goal = np.clip(q0 + rng.uniform(-0.25, 0.25, 9), sim.lower[:9], sim.upper[:9])
        sim.command(sc.arm, goal.tolist())
        sc.run(0.3)
        if sim.errors:
            sim.reboot([])
            sim.set_torque(True)
    assert watch.penetration <= MAX_PENETRATION, watch.penetration


def _energy(sim) -> tuple[float, float]:
    """The free block's kinetic energy (J) and its centre of mass's height (m)."""
    m, d = sim.physics.model, sim.physics.data
    b = sim.physics.block_body
    v = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, b, v, 0)   # [ω; v] at the CoM
    r = d.ximat[b].reshape(3, 3)
    inertia = r @ np.diag(m.body_inertia[b]) @ r.T
    kinetic = 0.5 * m.body_mass[b] * float(v[3:] @ v[3:]) + 0.5 * float(v[:3] @ inertia @ v[:3])
    return kinetic, float(d.xipos[b][2])


def test_block_let_go_on_the_top_stays_there_or_tips_off_beside_the_peg(held):
    """Pressed 5 mm into the destination peg's top, 5 mm off its axis, and let go: the hole
    over the peg's edge, the block's centre of mass is over no support (the top meets it
    only on a crescent beside the hole), so it tips: it rests on the top or leans on the
    peg, or falls beside it. Never down the peg, never flung: its kinetic energy never
    exceeds the potential energy it lost plus what the contacts held elastically (½ |f|
    depth each) when it was let go."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    d = np.array([0.005, 0.0, 0.0])
    sc.move_tool(above + d, 1.0)
    sc.move_tool(above + d - [0, 0, 0.025], 1.0)       # pressed 5 mm into the top
    assert sim.world.state is BlockState.HELD and sim.world.peg is None
    assert sim.contact_force[2] > 0.0
    stored = sum(0.5 * float(np.linalg.norm(c.force)) * max(0.0, -c.dist)
                 for c in sim.physics.contacts(everything=True)
                 if c.a.startswith("block_piece") or c.b.startswith("block_piece"))
    mass = sim.physics.model.body_mass[sim.physics.block_body]
    _, z0 = _energy(sim)
    worst = -math.inf
    sim.command([sim.desc.gripper.name], [1.2])
    for _ in range(300):
        sim.step(0.002)
        kinetic, z = _energy(sim)
        worst = max(worst, kinetic - mass * 9.81 * (z0 - z))
    assert worst <= stored, (worst, stored)
    assert sim.world.state in (BlockState.ON_PEG_TOP, BlockState.ON_TABLE)
    assert not sim.world.on_peg("destination")
    if sim.world.state is BlockState.ON_PEG_TOP:
        assert sim.world.peg == "destination"


def test_offset_is_drawn_once_per_move(held):
    """A jump of the goals (one joint-space command) draws a new offset; streamed small
    setpoints, however long, keep the one drawn. The true joints settle to it at most
    OFFSET_RATE per joint (drawn at once, a new move next to a peg threw the block 6-8 mm
    into the peg's top in one step)."""
    sc0 = held[0]
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    sim.cfg = dataclasses.replace(sim.cfg, imperfections=dataclasses.replace(
        sim.cfg.imperfections, repeatability=0.006))
    q = sim.goal[:9].copy()
    before = sim.offset[:9].copy()
    sim.command(sc.arm, (q + 0.1).tolist())              # a jump: a new move
    steps, settled = [], None
    for k in range(1, 200):                              # 0.2 rad, streamed
        last = sim.offset[:9].copy()
        sim.command(sc.arm, (q + 0.1 + 0.001 * k).tolist())
        sim.step(DT)
        steps.append(np.abs(sim.offset[:9] - last).max())
        if k == 50:
            settled = sim.offset[:9].copy()              # 0.5 s: settled (< 0.05 rad away)
    first = sim.offset[:9].copy()
    assert np.abs(first - before).max() > 0.0            # drawn
    assert np.array_equal(settled, first)                # one draw for the whole stream
    assert max(steps) <= OFFSET_RATE * DT * (1 + 1e-12)  # never a jump
    sim.command(sc.arm, q.tolist())                      # a jump back
    sc.run(0.5)
    assert not np.array_equal(sim.offset[:9], first)


def test_a_hard_press_on_the_table_stays_out_of_it(held, over=0.08):
    """The held block pressed straight down onto the table, ``over`` m past seating, in
    position mode at the stall torque: its lowest corner (from the block's pose and size)
    stays within 2 mm of the table, and nothing else (a pad, a link) goes deeper. (With the
    hand-written solver the arm's compliance pivoted the rigidly held block on its edge,
    5-16°, and upright-modelled a corner once went 4.5-8.5 mm in. On MuJoCo the block is
    held by the pads' friction: pushed up between the pads, which are as tall as it is
    (mjcf.PAD_HALF_SIZE), it stays flat and the pads' bottoms come down on the table and
    take the press, 0.2 mm in under ~60 N at 8 cm past seating.)"""
    sc0 = held[0]
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    w = sim.cfg.world
    half = np.array(w.block.size) / 2.0
    seat = np.array([0.30, 0.0, w.table_height + half[2]])
    sc.move_tool(seat + [0.0, 0.0, 0.03], 1.5)
    watch = _Watch(sim)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    worst = 0.0
    step = sim.step

    def checked(dt):
        nonlocal worst
        step(dt)
        pose = sim.world.block_pose()
        lowest = float((corners @ pose[:3, :3].T + pose[:3, 3])[:, 2].min())
        worst = max(worst, w.table_height - lowest)

    sim.step = checked
    sc.move_tool(seat - [0.0, 0.0, over], 2.0)
    assert sim.world.state is BlockState.HELD
    assert worst <= MAX_PENETRATION, worst
    assert watch.penetration <= MAX_PENETRATION, watch.penetration
