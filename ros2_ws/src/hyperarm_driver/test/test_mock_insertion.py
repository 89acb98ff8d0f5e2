"""Core tier: physical invariants of insertion (issue 9, item 2), as properties over drawn
commands (hypothesis), on the ROS-free simulation core.

- a misaligned block pressed down to any depth (even below the table), in position mode or
  current-limited, penetrates neither the table nor a peg by more than 2 mm after any
  step, a threaded one stays within the clearance (+2 mm of wall), and it is never flung:
  it moves at most as fast as the arm's joints can move it; settled, the limited joints
  exert at most their limits against the contact;
- torque (effort-only) presses never fling the block, nor push it more than 2 mm in;
- a block let go threaded rests within the radial clearance of the peg's axis; let go on
  the top with its centre over the top's disc, it stays on the top where it was;
- the repeatability offset is drawn once per move: streamed small setpoints (an approach, a
  press, a dither) keep it; a jump of the goals draws a new one.
"""
from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st
import pinocchio as pin

from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.mock.scenario import Scenario
from hyperarm_driver.mock.world import BlockState

pytestmark = [pytest.mark.core, pytest.mark.slow]

DT = 0.01
MAX_PENETRATION = 0.002   # m, issue 9 item 2
NO_SHRINK = (Phase.explicit, Phase.reuse, Phase.generate)   # a known failure: no minutes


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
    sc.grip(1.2, seconds=0.8)
    sc.move_tool(block + [0, 0, 0.12], 2.0)
    sc.move_tool(block, 1.5)
    sc.grip(0.0, 0.6, seconds=0.8)
    sc.move_tool(block + [0, 0, 0.12], 1.5)
    above = np.array([*dst.xy, w.table_height + dst.height + half + 0.02])
    sc.move_tool(above, 2.0)
    assert sim.world.state is BlockState.HELD
    return sc, above, half, w.table_height + dst.height


def _depth(sim) -> float:
    cs = sim.world.contacts(sim.tool_pose())
    return max((c.depth for c in cs), default=0.0)


class _Watch:
    """Checks after every simulation step of ``sim``: the worst penetration of the held
    block into the table or a peg (World.penetration: the geometry alone, no contact
    memory; on the peg it is threaded on, the excess over the radial clearance), and the
    block's largest step against what the arm can do: the block's displacement over a
    step divided by the bound dt·Σ_i |∂p/∂q_i|·vmax_i (every joint at its velocity limit,
    at the true joints)."""

    def __init__(self, sim) -> None:
        self.sim, self.data = sim, sim.model.createData()
        self.penetration, self.speed = 0.0, 0.0
        self.last = self._block()
        step = sim.step

        def checked(dt):
            step(dt)
            self.penetration = max(self.penetration, sim.world.penetration(sim.tool_pose()))
            b = self._block()
            if b is not None and self.last is not None:
                self.speed = max(self.speed, float(np.linalg.norm(b - self.last))
                                 / (dt * self._bound()))
            self.last = b

        sim.step = checked

    def _block(self):
        s = self.sim
        return s.world.block_pose(s.tool_pose())[:3, 3].copy() \
            if s.world.state is BlockState.HELD else None

    def _bound(self) -> float:
        s, nk = self.sim, self.sim.nk
        q = s.position[:nk] + s.offset[:nk]
        j = pin.computeFrameJacobian(s.model, self.data, q, s.tool_id,
                                     pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        r = self.last - s.tool_pose()[:3, 3]
        jp = j[:3] + np.cross(j[3:].T, r).T          # the block centre's linear Jacobian
        return float(np.linalg.norm(jp, axis=0) @ s.vmax[:nk])


@settings(max_examples=8, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(off=st.floats(0.003, 0.03), angle=st.floats(0.0, 2.0 * math.pi),
       depth=st.floats(0.0, 0.12), limited=st.booleans())
@example(off=0.005, angle=0.5 * math.pi, depth=0.12, limited=False)   # went through the
@example(off=0.005, angle=0.5 * math.pi, depth=0.09, limited=False)   # peg (issue 9)
@example(off=0.003, angle=math.pi, depth=0.12, limited=False)
@example(off=0.005, angle=0.5 * math.pi, depth=0.12, limited=True)    # 90 mm in, flung
@example(off=0.005, angle=0.0, depth=0.12, limited=True)              # 79 mm in, 62 m/s
def test_press_never_penetrates_nor_flings(held, off, angle, depth, limited):
    """Issue 9 item 2, after every simulation step: a misaligned block pressed down to any
    depth (4 cm under the table at most), in position mode or current-limited (current-
    based position, a limit just above each joint's load), penetrates neither the table nor
    a peg by more than 2 mm (whether it stays on the top, slides over the hole and threads:
    then within the clearance, or slides off the top and comes down beside the peg: this
    arm's springs push a block pressed straight down sideways at ~0.78 x the normal force,
    more than the friction 0.5), and is never flung: it moves at most as fast as the arm
    can move it. Settled, each current-limited joint exerts at most its limit against the
    contact: the contact's generalized force is what the limited joints can give."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    d = np.array([off * math.cos(angle), off * math.sin(angle), 0.0])
    sc.move_tool(above + d, 1.0)
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
    # settled: the joints' torques against the contact within their limits (2 %: the
    # yield converges over the steps)
    nk = sim.nk
    q = sim.position[:nk] + sim.offset[:nk]
    j = pin.computeFrameJacobian(sim.model, sim.model.createData(), q, sim.tool_id,
                                 pin.ReferenceFrame.LOCAL)
    need = pin.computeGeneralizedGravity(sim.model, sim.model.createData(), q) \
        - j.T @ sim.tool_wrench
    assert np.all(np.abs(need) <= sim.limit[:nk] * 1.02 + 1e-3), (need, sim.limit[:nk])


def _torque_press(held, off, angle, force):
    """Above the destination peg, ``off`` m from its axis towards ``angle``, the arm
    switched to torque control (effort-only commands, re-sent every 0.1 s): the holding
    torques plus Jᵀ of a push of ``force`` N down and 0.3 x that sideways, for 2 s."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    d = np.array([off * math.cos(angle), off * math.sin(angle), 0.0])
    sc.move_tool(above + d, 1.0)
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
def test_torque_press_never_flings(held, off, angle, force):
    """Effort-only (torque) commands pushing the held block down onto the peg or the table:
    the block moves at most as fast as the arm can move it (before the fix the contact
    spring in the torque-mode dynamics pushed the wrong way: 50-80 m/s), the states stay
    finite, it stays held."""
    sim, watch = _torque_press(held, off, angle, force)
    assert sim.world.state is BlockState.HELD
    assert np.all(np.isfinite(sim.position)) and np.all(np.isfinite(sim.velocity))
    assert watch.speed <= 1.0, watch.speed


def test_press_beside_the_peg_on_the_friction_cone_settles_within_the_limits(held):
    """The example test_press_never_penetrates_nor_flings generated once (Hypothesis draws
    constants from the modules loaded, so which examples it tries depends on what else the
    run imports): 29 mm off the destination peg, current-limited, pressed 11 cm down. The
    block comes down on the table sliding at its friction cone; settled, each limited
    joint's torque against the contact must be within its limit. (It was not: the yield
    was solved with the friction rows stuck while the contact solve let them slide, so
    joint1's yield alternated step to step, its contact torque 0.75 N·m against its
    0.52 N·m limit; the yield solve now takes the contact solve's sliding and dropped
    contacts.)"""
    inner = test_press_never_penetrates_nor_flings.hypothesis.inner_test
    inner(held, off=0.029259817282555344, angle=3.2379928555727426,
          depth=0.11235258705141944, limited=True)


@settings(max_examples=6, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(off=st.floats(0.0, 0.03), angle=st.floats(0.0, 2.0 * math.pi),
       force=st.floats(0.0, 30.0))
@example(off=0.00085, angle=0.781, force=19.4)    # 3-13 mm in before the step guard
def test_torque_press_never_penetrates(held, off, angle, force):
    """The penetration invariant for torque commands: the contact rows of the torque-mode
    joints are linearized once per step, so a block driven fast onto the table or turned
    against a peg's side went 3-13 mm in; the step guard (docs/mock.md) stops it at the
    last pose within 2 mm."""
    sim, watch = _torque_press(held, off, angle, force)
    assert watch.penetration <= MAX_PENETRATION, watch.penetration
    assert sim.world.state is BlockState.HELD


@settings(max_examples=6, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(off=st.floats(0.0, 0.0015), angle=st.floats(0.0, 2.0 * math.pi),
       push=st.floats(0.0, 0.01), push_angle=st.floats(0.0, 2.0 * math.pi))
def test_threaded_block_rests_within_the_clearance(held, off, angle, push, push_angle):
    """The block's hole aligned within the clearance: it threads; pushed sideways (up to
    1 cm of command) at the peg's base and let go, it rests within the clearance of the
    axis. (Aligned: the block where it really is, which is off the tool by the grasp.)"""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    grasp = sc.block_xyz() - above
    d = np.array([off * math.cos(angle) - grasp[0], off * math.sin(angle) - grasp[1], 0.0])
    base = above + d
    base[2] = sim.cfg.world.table_height + half + 0.005
    sc.move_tool(above + d, 1.0)
    sc.move_tool(base, 1.5)
    assert sim.world.peg == "destination"
    p = np.array([push * math.cos(push_angle), push * math.sin(push_angle), 0.0])
    sc.move_tool(base + p, 1.0)
    sc.grip(1.2, seconds=0.6)
    assert sim.world.state is BlockState.ON_PEG
    clearance = sim.cfg.world.clearance("destination")
    assert sim.world.misalignment("destination", sim.world.block_pose()) <= clearance + 1e-12


@settings(max_examples=5, deadline=None, derandomize=True, phases=NO_SHRINK,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**16))
def test_threaded_block_dragged_by_any_command_stays_out_of_the_wall(held, seed):
    """Threaded on the destination peg, 3 cm down, the block dragged by random joint-space
    commands (jumps of up to ±0.25 rad per joint, each held 0.3 s): it never goes more than
    2 mm past the clearance into the hole's wall nor into the table (solved against the
    plane of the wall's normal at the commanded joints, such drags went 1-3.6 cm in;
    docs/mock.md): the arm jams instead, its servos at their limits."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    grasp = sc.block_xyz() - above
    down = above - [grasp[0], grasp[1], 0.0]
    sc.move_tool(down, 1.0)
    sc.move_tool(down - [0.0, 0.0, 0.05], 1.5)
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


@pytest.mark.parametrize("angle", [0.0, 0.5 * math.pi, 1.25 * math.pi])
def test_threaded_block_pulled_sideways_is_held_by_the_wall_solve_itself(held, angle):
    """Threaded 3 cm down the destination peg (clear of the table), the tool commanded 3 cm
    sideways: the wall's contact solve itself keeps the block within 2 mm of the clearance,
    without the step guard refusing a step (solved against the plane of the wall's normal
    at the commanded joints, the block slid along it into the curved wall)."""
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    grasp = sc.block_xyz() - above
    down = above - [grasp[0], grasp[1], 0.0] - [0.0, 0.0, 0.05]
    sc.move_tool(down + [0.0, 0.0, 0.05], 1.0)
    sc.move_tool(down, 1.5)
    assert sim.world.peg == "destination"
    watch = _Watch(sim)
    guarded = sim.guarded_steps
    sc.move_tool(down + 0.03 * np.array([math.cos(angle), math.sin(angle), 0.0]), 1.0)
    sc.run(0.5)
    assert sim.world.state is BlockState.HELD
    assert watch.penetration <= MAX_PENETRATION, watch.penetration
    assert sim.guarded_steps == guarded


def test_block_let_go_on_the_top_stays_there(held):
    sc0, above, half, top = held
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    d = np.array([0.005, 0.0, 0.0])
    sc.move_tool(above + d, 1.0)
    sc.move_tool(above + d - [0, 0, 0.025], 1.0)       # pressed 5 mm into the top
    where = sc.block_xyz()
    sc.grip(1.2, seconds=0.6)
    assert sim.world.state is BlockState.ON_PEG_TOP and sim.world.peg == "destination"
    rest = sim.world.block_pose()[:3, 3]
    assert rest[:2] == pytest.approx(where[:2], abs=1e-9)
    assert rest[2] == pytest.approx(top + half, abs=1e-9)


def test_offset_is_drawn_once_per_move(held):
    """A jump of the goals (one joint-space command) draws a new offset; streamed small
    setpoints, however long, keep the one drawn. The true joints settle to it at most
    OFFSET_RATE per joint (drawn at once, a new move next to a peg threw the block 6-8 mm
    into the peg's top in one step)."""
    from hyperarm_driver.mock.joint_sim import OFFSET_RATE
    sc0 = held[0]
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    sim.cfg = dataclasses.replace(sim.cfg, imperfections=dataclasses.replace(
        sim.cfg.imperfections, repeatability=0.006))
    q = sim.goal[:9].copy()
    sim.command(sc.arm, (q + 0.1).tolist())              # a jump: a new move
    first = sim._offset_goal[:9].copy()
    assert np.abs(first).max() > 0.0
    steps = []
    for k in range(1, 200):                              # 0.2 rad, streamed
        before = sim.offset[:9].copy()
        sim.command(sc.arm, (q + 0.1 + 0.001 * k).tolist())
        sim.step(DT)
        steps.append(np.abs(sim.offset[:9] - before).max())
    assert np.array_equal(sim._offset_goal[:9], first)   # one draw for the whole stream
    assert np.array_equal(sim.offset[:9], first)         # settled to it, well within 2 s
    assert max(steps) <= OFFSET_RATE * DT * (1 + 1e-12)  # never a jump
    sim.command(sc.arm, q.tolist())                      # a jump back
    assert not np.array_equal(sim._offset_goal[:9], first)

@pytest.mark.parametrize("over", [0.04, 0.08])
def test_a_hard_press_on_the_table_pivots_the_block_on_its_edge(held, over):
    """The held block pressed straight down onto the table, ``over`` m past seating, in
    position mode at the stall torque: the arm's compliance tilts it (5-16°); its lowest
    corner (from the block's pose and size, not the mock's contact) stays within 2 mm of
    the table: it pivots on its edge. Upright-modelled, a corner went 4.5-8.5 mm in (an
    acceptance run)."""
    sc0 = held[0]
    sc = copy.deepcopy(sc0)
    sim = sc.sim
    w = sim.cfg.world
    half = np.array(w.block.size) / 2.0
    seat = np.array([0.30, 0.0, w.table_height + half[2]])
    sc.move_tool(seat + [0.0, 0.0, 0.03], 2.0)
    watch = _Watch(sim)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    worst = 0.0
    step = sim.step

    def checked(dt):
        nonlocal worst
        step(dt)
        pose = sim.world.block_pose(sim.tool_pose())
        worst = max(worst, w.table_height - float((corners @ pose[:3, :3].T + pose[:3, 3])[:, 2].min()))

    sim.step = checked
    sc.move_tool(seat - [0.0, 0.0, over], 2.0)
    pose = sim.world.block_pose(sim.tool_pose())
    tilt = math.degrees(math.acos(min(1.0, abs(float(pose[2, 2])))))
    assert sim.world.state is BlockState.HELD
    assert tilt > 3.0, tilt                        # the press does tilt it
    assert worst <= MAX_PENETRATION, worst
    assert watch.penetration <= MAX_PENETRATION, watch.penetration
