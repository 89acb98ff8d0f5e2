"""Collision model (coal), collision-aware IK and path checks (no ROS)."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.world import parse_world
from hyperarm_ik.collision import CollisionModel, check_joint_path, pose_path
from hyperarm_ik.errors import InvalidOptionError
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.solvers import make_solver, solver_names

pytestmark = pytest.mark.core

ARM = Kinematics()
CELL = {
    "table_height": -0.20,
    "pegs": {"source": {"xy": [0.35, 0.12], "height": 0.08, "radius": 0.008},
             "destination": {"xy": [0.35, -0.12], "height": 0.08, "radius": 0.008}},
    "block": {"size": [0.04, 0.04, 0.03], "hole_radius": 0.010, "start": "source"},
}
WORLD = parse_world(CELL)
HAND_DOWN = pin.utils.rotate("x", math.pi / 2)  # tool0's -y (the hand) pointing down


def _segment_distance(p1, q1, p2, q2) -> float:
    """Distance between segments [p1, q1] and [p2, q2] (Ericson, Real-Time Collision
    Detection 5.1.9): an independent reference for capsule contacts."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    denom = a * e - b * b
    s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 1e-15 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    return float(np.linalg.norm(p1 + d1 * s - (p2 + d2 * t)))


def test_self_collisions_agree_with_segment_distances():
    model = CollisionModel(ARM)
    assert not model.check(np.zeros(9))  # the stretched ready pose is free
    names = [c.name for c in ARM.desc.capsules]
    pairs = {(model.geom.geometryObjects[p.first].name, model.geom.geometryObjects[p.second].name)
             for p in model.geom.collisionPairs}
    assert ("link1", "link2") not in pairs and ("link7", "link9") not in pairs  # share joints
    assert ("link1", "link3") in pairs and ("link3", "gripper") in pairs
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(400):
        q = rng.uniform(ARM.lower, ARM.upper)
        got = {(c.a, c.b) for c in model.check(q)}
        segs = {cap.name: (a, b, cap.radius) for cap, a, b in ARM.desc.capsule_segments(q)}
        expected = set()
        for a, b in pairs:
            pa, qa, ra = segs[a]
            pb, qb, rb = segs[b]
            d = _segment_distance(pa, qa, pb, qb) - ra - rb
            if abs(d) < 1e-6:
                continue  # grazing: either answer is right
            if d < 0.0:
                expected.add((a, b))
        got_clear = {g for g in got if abs(_segment_distance(
            segs[g[0]][0], segs[g[0]][1], segs[g[1]][0], segs[g[1]][1])
            - segs[g[0]][2] - segs[g[1]][2]) >= 1e-6}
        assert got_clear == expected, q
        seen += bool(expected)
    assert seen >= 20 and {"base", "gripper", "link9"} <= set(names)  # folded ones collide


def test_world_contacts_name_the_obstacle_and_the_link():
    model = CollisionModel(ARM, WORLD)
    q = np.zeros(9)
    q[1] = math.radians(80)  # joint2 pitches the stretched arm down through the table
    names = {str(c) for c in model.check(q)}
    assert any(n.endswith("with table") for n in names), names
    assert not model.check(np.zeros(9))
    pole = parse_world({**CELL, "poles": {"pole1": {"xy": [0.25, 0.0], "radius": 0.015,
                                                     "height": 0.5}}})
    with_pole = CollisionModel(ARM, pole)
    assert "link3 with pole pole1" in {str(c) for c in with_pole.check(np.zeros(9))}


def _hand_down_at(model_kin, xyz):
    s = make_solver("default", model_kin)
    res = s.solve(np.asarray(xyz, dtype=float), HAND_DOWN, np.zeros(9),
                  position_tolerance=1e-6, orientation_tolerance=1e-6, timeout=2.0)
    assert res.success, res.message
    return res.q


def test_the_held_block_threads_a_peg_and_hits_the_table():
    model = CollisionModel(ARM, WORLD)
    peg = WORLD.peg("destination")
    top = WORLD.peg_top_z("destination")
    on_peg = _hand_down_at(ARM, (peg.xy[0], peg.xy[1], top - 0.01))  # block around the peg
    assert not model.check(on_peg, held=True)
    beside = _hand_down_at(ARM, (peg.xy[0] + 0.015, peg.xy[1], top - 0.01))
    assert "held block with peg destination" in {str(c) for c in model.check(beside, True)}
    low = _hand_down_at(ARM, (0.35, 0.0, WORLD.table_height + 0.01))
    assert "held block with table" in {str(c) for c in model.check(low, held=True)}


def test_the_hand_reaches_a_block_on_the_table_but_not_into_it():
    """The hand's capsules meet the table's top lowered by HAND_TABLE_ALLOWANCE (the finger
    pads meet the table itself, in the mock's MuJoCo model): tool0 at a block's centre on
    the table is free, tool0 3 cm into the table is refused, naming the hand."""
    from hyperarm_ik.collision import HAND_TABLE_ALLOWANCE

    model = CollisionModel(ARM, WORLD)
    z_table = WORLD.table_height
    on_table = _hand_down_at(ARM, (0.35, 0.0, z_table + 0.015))   # a 3 cm block's centre
    assert not model.check(on_table), [str(c) for c in model.check(on_table)]
    into = _hand_down_at(ARM, (0.35, 0.0, z_table - 0.03))
    hits = {str(c) for c in model.check(into)}
    assert any("with table (the hand's envelope)" in h for h in hits), hits
    # the allowance is the envelope's reach below the pads (5 mm), not more
    assert 0.005 <= HAND_TABLE_ALLOWANCE < 0.015


def test_target_inside_the_base_fails_with_the_pair():
    s = make_solver("default", ARM)
    s.use_collision_model(CollisionModel(ARM))
    res = s.solve(np.array([0.0, 0.0, 0.05]), None, np.zeros(9), position_only=True,
                  collisions="avoid", timeout=0.5)
    assert not res.success
    assert "in collision" in res.message or "no collision-free" in res.message
    assert res.contacts, res.message


def test_avoidance_finds_a_free_configuration_where_the_first_one_collides():
    q_true = np.array([0.359, -0.603, -1.202, -1.266, 0.82, 1.081, 0.279, 0.601, 0.114])
    t = ARM.forward(q_true)
    s = make_solver("default", ARM)
    first = s.solve(t[:3, 3], t[:3, :3], np.zeros(9), timeout=1.0)
    assert first.success and not CollisionModel(ARM, WORLD).check(first.q)
    # a pole through the middle of the arm of the first solution
    mid = ARM.desc.capsule_segments(first.q)[3]  # link4
    x, y = (0.5 * (mid[1] + mid[2]))[:2].tolist()
    cell = {**CELL, "poles": {"pole1": {"xy": [x, y], "radius": 0.01, "height": 0.6}}}
    model = CollisionModel(ARM, parse_world(cell))
    s.use_collision_model(model)
    checked = s.solve(t[:3, 3], t[:3, :3], np.zeros(9), timeout=1.0, collisions="check")
    assert not checked.success and "link4 with pole pole1" in checked.contacts
    assert "in collision: " in checked.message and "link4 with pole pole1" in checked.message
    avoided = s.solve(t[:3, 3], t[:3, :3], np.zeros(9), timeout=1.0, collisions="avoid")
    assert avoided.success, avoided.message
    assert not avoided.contacts and not model.check(avoided.q)
    again = s.solve(t[:3, 3], t[:3, :3], np.zeros(9), timeout=1.0, collisions="avoid")
    np.testing.assert_array_equal(again.q, avoided.q)  # deterministic with restarts too


@pytest.mark.parametrize("name", solver_names("arm"))
def test_every_solver_reports_collisions_honestly(name):
    s = make_solver(name, ARM)
    model = CollisionModel(ARM, WORLD)
    s.use_collision_model(model)
    q = np.zeros(9)
    q[1] = math.radians(80)
    t = ARM.forward(q)
    res = s.solve(t[:3, 3], t[:3, :3], q, collisions="check", timeout=0.5)
    assert res.contacts == [str(c) for c in model.check(res.q)]
    assert not res.success and "in collision" in res.message


def test_collision_options_are_checked():
    s = make_solver("default", ARM)
    with pytest.raises(InvalidOptionError, match="needs a collision model"):
        s.solve(np.array([0.4, 0.0, 0.2]), None, position_only=True, collisions="check")
    s.use_collision_model(CollisionModel(ARM))
    with pytest.raises(InvalidOptionError, match="collisions must be one of"):
        s.solve(np.array([0.4, 0.0, 0.2]), None, position_only=True, collisions="maybe")
    with pytest.raises(InvalidOptionError):
        CollisionModel(ARM, margin=-0.01)


def test_joint_path_check_finds_the_first_collision():
    model = CollisionModel(ARM, WORLD)
    a = np.zeros(9)
    b = np.zeros(9)
    b[1] = math.radians(80)          # ends below the table
    res = check_joint_path(model, a, b)
    assert not res.free and 0.0 < res.s <= 1.0 and res.contacts
    assert any(str(c).endswith("with table") for c in res.contacts)
    assert model.in_collision(res.q) and not model.in_collision(a)
    up = np.zeros(9)
    up[1] = math.radians(-40)
    assert check_joint_path(model, a, up).free
    with pytest.raises(InvalidOptionError):
        check_joint_path(model, a, up, max_step=0.0)


def test_a_path_may_escape_a_contact_it_starts_in_but_not_go_deeper():
    """``escape``: the arm measured touching the table (a press pushed it there) may leave
    along any path that gets no deeper; a path that presses further in fails, naming the
    depths; without ``escape`` the start itself fails."""
    model = CollisionModel(ARM, WORLD)
    a = np.zeros(9)
    lo, hi = 0.0, math.radians(80)            # bisect joint2 to just touching the table
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        a[1] = mid
        lo, hi = (lo, mid) if model.in_collision(a) else (mid, hi)
    a[1] = hi + math.radians(0.5)             # a little way in (a few mm)
    depth = model.clearance_gradient(a)[0]
    assert depth < 0.0
    up, down = a.copy(), a.copy()
    up[1] -= math.radians(20)
    down[1] += math.radians(5)
    assert not check_joint_path(model, a, up).free           # the start is in collision
    out = model.check_path(a, up, escape=True)
    assert out.free, out.message
    deeper = model.check_path(a, down, escape=True)
    assert not deeper.free and "deeper into a contact" in deeper.message, deeper.message
    assert model.clearance_gradient(deeper.q)[0] < depth
    # leaving, then coming back into the table further on: caught as a plain collision
    back = a.copy()
    back[1] += math.radians(10)
    via = model.check_path(up, back)
    assert not via.free
    free_start = model.check_path(np.zeros(9), up, escape=True)   # no contact: as without
    assert free_start.free


def test_vertical_approach_to_a_peg_is_checked_along_the_line():
    model = CollisionModel(ARM, WORLD)
    s = make_solver("default", ARM)
    peg = WORLD.peg("destination")
    top = WORLD.peg_top_z("destination")

    def solve(p, r, seed):
        return s.solve(p, r, seed, position_tolerance=1e-5, orientation_tolerance=1e-4)

    def pose(x, y, z):
        t = np.eye(4)
        t[:3, :3] = HAND_DOWN
        t[:3, 3] = (x, y, z)
        return t
    start = _hand_down_at(ARM, (peg.xy[0], peg.xy[1], top + 0.08))
    # holding the block, straight down onto the peg: the hole threads it
    down = pose_path(ARM, solve, model, pose(peg.xy[0], peg.xy[1], top + 0.08),
                     pose(peg.xy[0], peg.xy[1], top - 0.01), start, held=True)
    assert down.free, down.message
    assert down.samples >= 18  # 9 cm in 5 mm steps
    # 15 mm off the axis the block lands on the peg top
    off = pose_path(ARM, solve, model, pose(peg.xy[0] + 0.015, peg.xy[1], top + 0.08),
                    pose(peg.xy[0] + 0.015, peg.xy[1], top - 0.01), start, held=True)
    assert not off.free and "held block with peg destination" in off.message
