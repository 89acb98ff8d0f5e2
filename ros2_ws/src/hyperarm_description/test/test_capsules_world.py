"""Core tests of the collision capsules and the work-cell (world) schema (no rclpy)."""
from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET

import coal
import numpy as np
import pinocchio as pin
import pytest
import yaml

from hyperarm_description import DescriptionError, load_description
from hyperarm_description.model import default_description_path, parse_description
from hyperarm_description.urdf import generate_urdf
from hyperarm_description.world import (WorldSpecError, load_world, parse_world,
                                        MOCK_WORLD_KEYS)

pytestmark = pytest.mark.core

LINKS = [f"link{i}" for i in range(1, 10)]


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load(default_description_path().read_text())


def _mutate(data: dict, fn) -> dict:
    out = copy.deepcopy(data)
    fn(out)
    return out


def test_every_link_and_the_gripper_has_one_capsule():
    desc = load_description()
    assert [c.name for c in desc.capsules] == [*LINKS, "gripper", "base"]
    assert desc.capsule("base").frame == "base_link"
    assert desc.capsule("gripper").frame == "tool0"
    for c in desc.capsules:
        assert c.radius > 0 and c.length > 0
    with pytest.raises(DescriptionError, match="no capsule named 'elbow'"):
        desc.capsule("elbow")


def test_link_capsules_run_along_their_segment():
    """Links 1-7: the segment goes from joint i's axis to joint i+1's (x of the link frame),
    so at any q its ends are at the joint origins computed from the DH table."""
    desc = load_description()
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.uniform(desc.lower_limits(), desc.upper_limits())
        frames = desc.frame_poses(q)
        segs = {c.name: (a, b) for c, a, b in desc.capsule_segments(q)}
        for i in range(1, 8):
            a, b = segs[f"link{i}"]
            assert a == pytest.approx(frames[f"link{i}"][:3, 3], abs=1e-12)
            assert b == pytest.approx(frames[f"link{i + 1}"][:3, 3], abs=1e-12)
        assert frames["tool0"] == pytest.approx(desc.dh_forward(q), abs=1e-12)


def test_urdf_collision_is_cylinder_plus_two_spheres_per_capsule():
    desc = load_description()
    root = ET.fromstring(generate_urdf(desc))
    by_link = {ln.get("name"): ln for ln in root.iter("link")}
    for c in desc.capsules:
        cols = {col.get("name"): col for col in by_link[c.frame].findall("collision")}
        cyl = cols[f"{c.name}_cylinder"].find("geometry/cylinder")
        assert float(cyl.get("radius")) == c.radius and float(cyl.get("length")) == c.length
        ends = [cols[f"{c.name}_end{k}"] for k in (0, 1)]
        a, b = c.endpoints()
        for col, p in zip(ends, (a, b)):
            assert float(col.find("geometry/sphere").get("radius")) == c.radius
            xyz = [float(v) for v in col.find("origin").get("xyz").split()]
            assert xyz == pytest.approx(p, abs=1e-12)
    n = sum(len(ln.findall("collision")) for ln in root.iter("link"))
    assert n == 3 * len(desc.capsules)


@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
def test_pinocchio_geometry_matches_capsule_segments(variant):
    """The URDF's collision spheres, placed by pinocchio, sit on the capsule ends the
    description computes from the DH table (same frames, no drift between the two)."""
    desc = load_description(variant=variant)
    urdf = generate_urdf(desc)
    model = pin.buildModelFromXML(urdf)
    geom = pin.buildGeomFromUrdfString(model, urdf, pin.GeometryType.COLLISION)
    data, gdata = model.createData(), pin.GeometryData(geom)
    base = model.getFrameId("base_link")
    for _ in range(20):
        q = pin.randomConfiguration(model)
        q[model.joints[model.getJointId("gripper")].idx_q] = 0.0
        pin.framesForwardKinematics(model, data, q)
        pin.updateGeometryPlacements(model, data, geom, gdata)
        arm_q = np.array([q[model.joints[model.getJointId(f"joint{i}")].idx_q]
                          for i in range(1, 10)])
        for c, a, b in desc.capsule_segments(arm_q):
            for k, p in enumerate((a, b)):
                # pinocchio names a link's geometries <link>_<index>, in URDF order:
                # the capsule's cylinder, then its two end spheres
                gid = geom.getGeometryId(f"{c.frame}_{k + 1}")
                sphere = geom.geometryObjects[gid].geometry
                assert isinstance(sphere, coal.Sphere) and sphere.radius == c.radius
                rel = data.oMf[base].actInv(gdata.oMg[gid])
                assert rel.translation == pytest.approx(p, abs=1e-9)


@pytest.mark.parametrize("mutation,field", [
    (lambda d: d["collision"]["capsules"].pop("link4"), r"missing capsule\(s\) \['link4'\]"),
    (lambda d: d["collision"]["capsules"]["link2"].update(radius=0.0),
     r"collision\.capsules\.link2\.radius: must be > 0"),
    (lambda d: d["collision"]["capsules"]["link2"].update(length=-0.1),
     r"collision\.capsules\.link2\.length: must be > 0"),
    (lambda d: d["collision"]["capsules"]["gripper"].update(frame="hand"),
     r"collision\.capsules\.gripper\.frame: 'hand' is not a robot link"),
    (lambda d: d["collision"]["capsules"]["link3"].update(colour="red"),
     r"collision\.capsules\.link3: unknown key"),
    (lambda d: d["collision"]["capsules"]["link3"].update(rpy=[0, "sideways", 0]),
     r"collision\.capsules\.link3\.rpy\[1\]: cannot read angle"),
    (lambda d: d["collision"]["capsules"]["link3"].pop("xyz"),
     r"collision\.capsules\.link3\.xyz: missing"),
    (lambda d: d.pop("collision"), r"collision: missing"),
])
def test_bad_capsule_names_the_field(raw, mutation, field):
    with pytest.raises(DescriptionError, match=field):
        parse_description(_mutate(raw, mutation), "arm")


WORLD = {
    "table_height": -0.2,
    "table": {"x": [-0.3, 0.8], "y": [-0.5, 0.5]},
    "pegs": {"source": {"xy": [0.35, 0.12], "height": 0.08, "radius": 0.008},
             "destination": {"xy": [0.35, -0.12], "height": 0.08, "radius": 0.008}},
    "block": {"size": [0.04, 0.04, 0.03], "hole_radius": 0.01, "mass": 0.05,
              "start": "source"},
    "poles": {"pole1": {"xy": [0.25, 0.0], "radius": 0.015, "height": 0.5}},
}


def test_world_parses_with_units():
    w = parse_world(WORLD)
    assert w.table_height == -0.2 and w.table.x_range == (-0.3, 0.8)
    assert w.clearance("destination") == pytest.approx(0.002)
    assert w.peg_top_z("source") == pytest.approx(-0.12)
    pole = w.pole("pole1")
    assert (pole.z_min, pole.z_max) == pytest.approx((-0.2, 0.3)) and pole.height == 0.5
    no_block = parse_world(_mutate(WORLD, lambda d: d.pop("block")))
    assert no_block.block is None
    with pytest.raises(WorldSpecError, match="no block"):
        no_block.clearance("source")
    unbounded = parse_world(_mutate(WORLD, lambda d: d.pop("table")))
    assert unbounded.table.contains_xy(1e6, -1e6)


@pytest.mark.parametrize("mutation,field", [
    (lambda d: d.pop("table_height"), r"world\.table_height: missing"),
    (lambda d: d["table"].update(x=[1.0, 0.0]), r"world\.table\.x: min 1 must be < max 0"),
    (lambda d: d["pegs"]["source"].update(xy=[2.0, 0.0]), r"world\.pegs\.source\.xy: .* off"),
    (lambda d: d["pegs"]["source"].update(radius=0.01), r"world\.pegs\.source\.radius"),
    (lambda d: d["block"].update(start="nowhere"), r"world\.block\.start: 'nowhere' is not"),
    (lambda d: d["poles"]["pole1"].update(xy=[0.35, 0.11]), r"world\.poles\.pole1\.xy: too close"),
    (lambda d: d["poles"]["pole1"].update(radius=-1), r"world\.poles\.pole1\.radius: must be > 0"),
    (lambda d: d["poles"]["pole1"].pop("height"), r"world\.poles\.pole1\.height: missing"),
    (lambda d: d.update(lava=True), r"world: unknown key\(s\) \['lava'\]"),
    (lambda d: d.update(pegs={}), r"world\.pegs: must be a non-empty mapping"),
])
def test_bad_world_names_the_field(mutation, field):
    with pytest.raises(WorldSpecError, match=field):
        parse_world(_mutate(WORLD, mutation))


def test_world_extra_keys_and_own_error_class():
    data = _mutate(WORLD, lambda d: d.update(friction=0.5))
    with pytest.raises(WorldSpecError, match="friction"):
        parse_world(data)
    assert parse_world(data, extra_keys=MOCK_WORLD_KEYS).pegs

    class Mine(ValueError):
        pass
    with pytest.raises(Mine, match=r"world\.table_height"):
        parse_world(_mutate(WORLD, lambda d: d.pop("table_height")), error=Mine)


def test_load_world_reads_a_work_cell_file(tmp_path):
    f = tmp_path / "cell.yaml"
    f.write_text(yaml.safe_dump({"servo": {"lag": 0.1}, "world": {**WORLD, "friction": 0.3}}))
    assert load_world(f).pole("pole1").radius == 0.015
    (tmp_path / "empty.yaml").write_text("servo: {}\n")
    with pytest.raises(WorldSpecError, match="no 'world' mapping"):
        load_world(tmp_path / "empty.yaml")
    with pytest.raises(WorldSpecError, match="cannot read work-cell file"):
        load_world(tmp_path / "missing.yaml")
    assert math.isfinite(load_world(f).table_height)
