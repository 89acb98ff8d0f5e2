"""Scenes the force and task nodes need (issue 9, item 6): the shipped work cells, poles
that the links' capsules touch, camera dropouts; core tier, plus debug/contacts through the
node."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.world import load_world
from hyperarm_driver.mock.camera import Camera
from hyperarm_driver.mock.config import default_workcell_path, load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.mock.world import BlockState

CELLS = default_workcell_path().parent
DT = 0.01


@pytest.mark.core
@pytest.mark.parametrize("name", ["workcell.yaml", "workcell_pole.yaml", "workcell_post.yaml",
                                  "workcell_no_block.yaml", "workcell_rail.yaml"])
def test_shipped_work_cells_load_for_the_mock_and_the_ik(name):
    cfg = load_mock_config(CELLS / name)
    assert load_world(CELLS / name) == cfg.world.spec     # the IK reads the same cell
    assert (cfg.world.block is None) == (name == "workcell_no_block.yaml")
    assert bool(cfg.world.poles) == (name in ("workcell_pole.yaml", "workcell_post.yaml"))


@pytest.mark.core
def test_rail_cell_pegs_are_beyond_reach_from_one_rail_position():
    desc = load_description(variant="rail_arm")
    cfg = load_mock_config(CELLS / "workcell_rail.yaml")
    reach = sum(math.hypot(j.dh.a, j.dh.d) for j in desc.joints)   # m, fully stretched
    a, b = (np.array(p.xy) for p in cfg.world.pegs)
    assert np.linalg.norm(a - b) > 2.0 * reach            # no single base position
    for p in (a, b):                                       # each from some rail position
        assert abs(p[0]) - desc.rail.upper < 0.5 * reach
        assert cfg.world.spec.table.contains_xy(*p)


@pytest.mark.core
def test_no_block_cell_runs_and_grasps_nothing():
    sim = JointSim(load_description(), load_mock_config(CELLS / "workcell_no_block.yaml"))
    sim.command(["gripper"], [0.0], [0.6])
    for _ in range(50):
        sim.step(DT)
    assert sim.world.state is BlockState.ABSENT and "block" not in sim.truth()
    assert sim.take_events() == []


def _sweep(limit):
    """joint1 commanded from 0 to 1.6 rad, the arm stretched, through the pole (at 45°)."""
    cfg = load_mock_config(CELLS / "workcell_pole.yaml")
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0, seed=2))
    sim = JointSim(load_description(), cfg)
    for _ in range(20):
        sim.step(DT)
    assert not sim.link_contacts
    sim.command(["joint1"], [1.6], [limit] if limit else [])
    for _ in range(150):
        sim.step(DT)
    return sim


@pytest.mark.core
def test_position_arm_stops_against_a_pole_with_efforts():
    sim = _sweep(None)
    pole = sim.cfg.world.poles[0]
    assert sim.position[0] < 1.0                           # stopped far short of 1.6 rad
    (link, name, _, force), = sim.link_contacts
    assert name == pole.name and link == "link4"
    assert np.linalg.norm(force) > 5.0                     # N: pushing hard
    assert abs(sim.effort[0]) > 0.5 * sim.stall[0]         # joint1 pushes back
    # the capsule is at most 2 mm into the pole
    cap = sim.desc.capsule(link)
    sim._tool_at(sim.position[:9])
    a, b = (sim.data.oMf[sim.model.getFrameId(cap.frame)].act(p) for p in cap.endpoints())
    d = np.cross(b - a, np.r_[pole.xy, 0.0] - a)[2] / np.linalg.norm((b - a)[:2])
    assert abs(d) > cap.radius + pole.radius - 0.002


@pytest.mark.core
def test_soft_arm_conforms_to_a_pole():
    """A low current limit: the joint gives way at its limit and the link rests on the pole
    with a small force (Fig. 4 of the paper), instead of pushing through or hard."""
    soft = _sweep(0.3)
    hard = _sweep(None)
    assert soft.position[0] < 1.0 and soft.link_contacts
    assert abs(soft.effort[0]) == pytest.approx(soft.limit[0], rel=1e-6)
    f_soft = np.linalg.norm(soft.link_contacts[0][3])
    f_hard = np.linalg.norm(hard.link_contacts[0][3])
    assert 0.0 < f_soft < 0.5 * f_hard       # the rest is held by the other joints' springs


@pytest.mark.core
def test_camera_dropout_for_a_period_and_for_good(tmp_path):
    import yaml
    raw = yaml.safe_load(default_workcell_path().read_text())
    raw["camera"]["dropouts"] = [{"start": 0.3, "duration": 0.2}, {"start": 1.0}]
    f = tmp_path / "cell.yaml"
    f.write_text(yaml.safe_dump(raw))
    cfg = load_mock_config(f)
    cam = Camera(cfg.camera, np.eye(4))
    dropped = {}
    for k in range(150):
        for frame in cam.step(k * DT, lambda: {"block": np.eye(4)}):
            dropped[round(frame.stamp, 1)] = frame.dropped
    assert not dropped[0.0] and not dropped[0.2] and dropped[0.3] and dropped[0.4]
    assert not dropped[0.5] and not dropped[0.9] and dropped[1.0] and dropped[1.3]
    raw["camera"]["dropouts"] = [{"start": -1.0}]
    f.write_text(yaml.safe_dump(raw))
    with pytest.raises(ValueError, match=r"camera\.dropouts\[0\]\.start: must be >= 0"):
        load_mock_config(f)


@pytest.mark.node
def test_link_contacts_on_debug_topic_and_in_diagnostics(rclpy_context, executor, wait_for):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from hyperarm_description.qos import qos_for
    from hyperarm_driver.mock_driver_node import MockDriver

    node = MockDriver(context=rclpy_context, parameter_overrides=[
        Parameter("workcell_file", value=str(CELLS / "workcell_pole.yaml")),
        Parameter("diagnostics_period", value=0.2)])
    executor.add_node(node)
    probe = rclpy.create_node("probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    contacts, diags = [], []
    probe.create_subscription(DiagnosticArray, contract.CONTACTS_TRUTH, contacts.append,
                              qos_for(contract.CONTACTS_TRUTH))
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: diags.extend(m.status), qos_for(contract.DIAGNOSTICS))
    pub = probe.create_publisher(JointState, contract.JOINT_COMMAND,
                                 qos_for(contract.JOINT_COMMAND))
    executor.add_node(probe)
    wait_for(lambda: pub.get_subscription_count() > 0, 10.0, what="joint_command subscriber")
    pub.publish(JointState(name=["joint1"], position=[1.6]))
    wait_for(lambda: contacts and contacts[-1].status, 10.0, what="a link on the pole")
    st = contacts[-1].status[0]
    values = {kv.key: kv.value for kv in st.values}
    assert values["link"] == "link4" and values["pole"] == "pole1"
    wait_for(lambda: any(s.name.endswith("work_cell") and "link4:pole1" in
                         {kv.key: kv.value for kv in s.values}.get("link_contacts", "")
                         
                         for s in diags), 10.0, what="link contacts in diagnostics")


def _pole_depth(sim) -> float:
    """Deepest capsule-pole interference (m) at the present joints, measured afresh from the
    geometry (no contact memory): 0 without contact."""
    sim._tool_at(sim.position[:sim.nk])
    segments = []
    for cap in sim.desc.capsules:
        m = sim.data.oMf[sim.model.getFrameId(cap.frame)]
        a, b = (m.act(p) for p in cap.endpoints())
        segments.append((cap.name, cap.radius, a, b))
    return max((c.depth for c in sim.world.pole_contacts(segments)), default=0.0)


@pytest.mark.core
@pytest.mark.parametrize("seed", [9, 11, 18, 40])
def test_no_link_passes_through_a_pole_whatever_is_commanded(seed):
    """Physical invariant (issue 9): position-mode joint goals, jumps and streams drawn at
    random across the pole, with the shipped repeatability (a new move's offset): no link
    is ever more than 2 mm into the pole, at any step, and no joint ever moves more than
    twice its velocity limit in a step (the failures fixed here: an offset drawn anew while a
    link pressed on the pole put it 9 mm in, and the contact solve then threw the arm through
    it, 2.5 rad in one step)."""
    cfg = load_mock_config(CELLS / "workcell_pole.yaml")
    cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(cfg.imperfections,
                                                                     seed=seed))
    sim = JointSim(load_description(), cfg)
    rng = np.random.default_rng(seed)
    arm = [f"joint{i}" for i in range(1, 10)]
    lo, hi = sim.lower[:9], sim.upper[:9]
    deepest, fastest, touched = 0.0, 0.0, 0
    q = np.zeros(9)
    for move in range(12):
        goal = np.clip(rng.uniform(-1.0, 1.0, 9) * np.r_[2.0, np.full(8, 1.0)], lo, hi)
        goal[0] = rng.uniform(0.2, 1.6)        # joint1 swings the arm at the pole (45°)
        streamed = move % 2 == 1
        n = 40 if streamed else 1
        for k in range(1, n + 1):
            sim.command(arm, (q + (goal - q) * k / n).tolist())
            for _ in range(2 if streamed else 120):
                before = sim.position[:9].copy()
                sim.step(DT)
                fastest = max(fastest, float(np.max(np.abs(sim.position[:9] - before)
                                                    / (sim.vmax[:9] * DT))))
                deepest = max(deepest, _pole_depth(sim))
                touched += bool(sim.link_contacts)
            if sim.errors:
                sim.reboot([])
                sim.set_torque(True)
        q = goal
    assert touched > 20, "the random goals never drove a link onto the pole"
    assert deepest <= 0.002, f"a link went {deepest * 1e3:.1f} mm into the pole"
    assert fastest <= 2.0 + 1e-9, f"a joint moved {fastest:.2f} x its velocity limit in a step"


@pytest.mark.core
def test_a_new_move_while_a_link_presses_a_pole_draws_its_offset_once_free():
    """The move rule's contact clause: a new move commanded while a link touches a pole
    keeps the offset (the contact holds the arm) and draws it at the first step free of
    contact."""
    sim = _sweep(None)
    assert sim.link_contacts
    first = sim.offset[:9].copy()
    cfg = sim.cfg
    sim.cfg = dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.006))
    sim.command(["joint1"], [0.9])           # a new move (a jump of the goal), still pressing
    sim.step(DT)
    assert sim.link_contacts and np.array_equal(sim.offset[:9], first)
    sim.command(["joint1"], [0.0])           # away from the pole
    for _ in range(150):
        sim.step(DT)
        if not sim.link_contacts:
            break
    sim.step(DT)
    assert not sim.link_contacts
    assert not np.array_equal(sim.offset[:9], first)


@pytest.mark.core
@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
def test_position_arm_swung_into_a_thick_post_stops_and_overloads(variant, tmp_path):
    """The shipped post cell's 55 mm-radius post 0.30 m out, joint1 swung hard into it: the
    arm once went through (0.56 to 2.1 rad in 0.1 s); it must stop at the post, at most 2 mm
    in, until joint1 overloads."""
    import yaml
    raw = yaml.safe_load((CELLS / "workcell_post.yaml").read_text())
    assert raw["world"]["poles"]["post"]["radius"] == 0.055
    raw["imperfections"].update(seed=1)
    (tmp_path / "post.yaml").write_text(yaml.safe_dump(raw))
    sim = JointSim(load_description(variant=variant), load_mock_config(tmp_path / "post.yaml"))
    arm = [f"joint{i}" for i in range(1, 10)]
    sim.command(arm, [0.0] * 9)
    for _ in range(100):
        sim.step(DT)
    j1 = sim._index["joint1"]
    sim.command(["joint1"], [2.1])
    deepest, furthest = 0.0, 0.0
    for _ in range(400):
        sim.step(DT)
        deepest = max(deepest, _pole_depth(sim))
        furthest = max(furthest, float(sim.position[j1]))
    assert furthest < 1.0, f"joint1 got to {furthest:.2f} rad: through the post"
    assert deepest <= 0.002, f"a link went {deepest * 1e3:.1f} mm into the post"
    assert sim.errors.get("joint1") == "overload", sim.errors
