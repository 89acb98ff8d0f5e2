"""Core tests of the robot description: YAML, validation, URDF, pinocchio (no rclpy)."""
from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
import yaml

from hyperarm_description import DescriptionError, load_description, parse_angle
from hyperarm_description.model import default_description_path, parse_description
from hyperarm_description.pinocchio_model import build_model
from hyperarm_description.urdf import generate_urdf, main as urdf_main, rpy_from_matrix

pytestmark = pytest.mark.core

# Table I of Danko & Oh: (theta rad, d mm, a mm, alpha rad)
TABLE_I = [
    (0, 0, 96.8, -math.pi / 2), (0, 0, 90.5, math.pi / 2), (0, 0, 90.5, -math.pi / 2),
    (0, 0, 88, math.pi / 2), (0, 0, 88, -math.pi / 2), (0, 0, 77.8, math.pi / 2),
    (0, 0, 71.8, -math.pi / 2), (0, 0, 0, -3 * math.pi / 2), (0, 190.2, 0, -math.pi / 2),
]


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load(default_description_path().read_text())


def test_dh_table_is_table_one():
    desc = load_description()
    assert [j.name for j in desc.joints] == [f"joint{i}" for i in range(1, 10)]
    for j, (theta, d_mm, a_mm, alpha) in zip(desc.joints, TABLE_I):
        assert j.dh.theta == pytest.approx(theta, abs=1e-15)
        assert j.dh.d == pytest.approx(d_mm / 1000.0, abs=1e-15)
        assert j.dh.a == pytest.approx(a_mm / 1000.0, abs=1e-15)
        assert j.dh.alpha == pytest.approx(alpha, abs=1e-15)


def test_default_limits_are_150_degrees_and_gripper_separate():
    desc = load_description()
    for j in desc.joints:
        assert (j.lower, j.upper) == pytest.approx((-math.radians(150), math.radians(150)))
    assert desc.gripper.name == "gripper" and desc.gripper.servo.id == 10
    assert [j.servo.id for j in desc.joints] == list(range(1, 10))
    assert desc.rail is None and desc.root_frame == "base_link"


def test_rail_variant():
    desc = load_description(variant="rail_arm")
    assert desc.rail is not None
    assert (desc.rail.lower, desc.rail.upper) == (-1.5, 1.5)
    assert desc.kinematic_joint_names[0] == "rail"
    assert desc.root_frame == "world"
    assert desc.lower_limits().shape == (10,)


@pytest.mark.parametrize("text,expected", [
    ("-pi/2", -math.pi / 2), ("-3*pi/2", -3 * math.pi / 2), ("pi", math.pi),
    ("150 deg", math.radians(150)), (0.25, 0.25), ("2pi/3", 2 * math.pi / 3),
])
def test_parse_angle(text, expected):
    assert parse_angle(text, "x") == pytest.approx(expected, abs=1e-15)


@pytest.mark.parametrize("bad", ["pie", "1/0", "nan deg", True, None, float("inf")])
def test_parse_angle_rejects(bad):
    with pytest.raises(DescriptionError, match="where"):
        parse_angle(bad, "where")


def _mutate(raw: dict, fn) -> dict:
    data = copy.deepcopy(raw)
    fn(data)
    return data


@pytest.mark.parametrize("mutation,field", [
    (lambda d: d["arm"]["joints"].pop(4), r"arm\.joints: the arm has 9 joints, found 8"),
    (lambda d: d["arm"]["joints"][2].update(lower="100 deg", upper="-100 deg"),
     r"arm\.joints\[2\] \(joint3\)\.lower/upper: lower limit .* must be < upper"),
    (lambda d: d["arm"]["joints"][0]["dh"].pop("a"), r"arm\.joints\[0\] \(joint1\)\.dh\.a: missing"),
    (lambda d: d["arm"]["joints"][1]["dh"].update(alpha="sideways"),
     r"arm\.joints\[1\] \(joint2\)\.dh\.alpha: cannot read angle"),
    (lambda d: d["arm"]["joints"][5]["servo"].update(model="AX-12"),
     r"arm\.joints\[5\] \(joint6\)\.servo\.model: unknown servo model 'AX-12'"),
    (lambda d: d["arm"]["joints"][6]["servo"].update(id=3),
     r"arm\.joints\[6\] \(joint7\)\.servo\.id: ID 3 already used by joint3"),
    (lambda d: d["arm"]["joints"][3]["link"].update(mass=-1.0),
     r"arm\.joints\[3\] \(joint4\)\.link\.mass: must be > 0"),
    (lambda d: d["arm"]["joints"][3].pop("name"), r"arm\.joints\[3\]\.name: missing"),
    (lambda d: d["gripper"].update(lower=1.0, upper=0.5), r"gripper\.lower/upper"),
    (lambda d: d.pop("gripper"), r"^gripper: missing|\.gripper: missing"),
])
def test_bad_yaml_names_the_field(raw, mutation, field):
    with pytest.raises(DescriptionError, match=field):
        parse_description(_mutate(raw, mutation), "arm")


def test_bad_rail_names_the_field(raw):
    data = _mutate(raw, lambda d: d["variants"]["rail_arm"]["rail"].update(lower=2.0, upper=1.0))
    with pytest.raises(DescriptionError, match=r"variants\.rail_arm\.rail\.lower/upper"):
        parse_description(data, "rail_arm")
    parse_description(data, "arm")  # the fixed-base variant does not read the rail


def test_unknown_variant_and_missing_file(tmp_path):
    with pytest.raises(DescriptionError, match="unknown variant 'boat'"):
        load_description(variant="boat")
    with pytest.raises(DescriptionError, match="cannot read robot description"):
        load_description(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("arm: [unclosed")
    with pytest.raises(DescriptionError, match="not valid YAML"):
        load_description(bad)


def test_rpy_roundtrip():
    rng = np.random.default_rng(3)
    for _ in range(200):
        r = pin.rpy.rpyToMatrix(*rng.uniform(-3, 3, 3))
        assert np.allclose(pin.rpy.rpyToMatrix(*rpy_from_matrix(r)), r, atol=1e-12)
    for r in (pin.rpy.rpyToMatrix(0.3, math.pi / 2, 0.2), pin.rpy.rpyToMatrix(0.3, -math.pi / 2, 0.2)):
        assert np.allclose(pin.rpy.rpyToMatrix(*rpy_from_matrix(r)), r, atol=1e-12)


@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
def test_urdf_pinocchio_matches_dh_on_1000_configurations(variant):
    desc = load_description(variant=variant)
    model = build_model(desc)
    data = model.createData()
    tool = model.getFrameId("tool0")
    base = model.getFrameId("base_link")
    rng = np.random.default_rng(42)
    worst = 0.0
    for _ in range(1000):
        q = rng.uniform(desc.lower_limits(), desc.upper_limits())
        pin.framesForwardKinematics(model, data, q)
        arm_q = q[1:] if desc.rail else q
        # tool pose relative to base_link, so the rail variant is checked the same way
        rel = data.oMf[base].actInv(data.oMf[tool]).homogeneous
        dh = desc.dh_forward(arm_q)
        worst = max(worst, float(np.abs(rel[:3, 3] - dh[:3, 3]).max()),
                    float(np.abs(rel[:3, :3] - dh[:3, :3]).max()))
    assert worst < 1e-9
    if desc.rail:
        # the rail moves base_link along world x by q_rail (plus the mount offset)
        q = np.zeros(model.nq)
        q[0] = 0.7
        pin.framesForwardKinematics(model, data, q)
        assert data.oMf[base].translation == pytest.approx(
            np.array(desc.rail.mount_xyz) + [0.7, 0, 0], abs=1e-12)


@pytest.mark.parametrize("variant", ["arm", "rail_arm"])
def test_urdf_limits_equal_yaml(variant):
    desc = load_description(variant=variant)
    root = ET.fromstring(generate_urdf(desc))
    joints = {j.get("name"): j for j in root.iter("joint")}
    expected = desc.limits_by_name()
    movable = {n for n, j in joints.items() if j.get("type") != "fixed"}
    assert movable == set(expected)
    for name, (lo, hi) in expected.items():
        limit = joints[name].find("limit")
        assert float(limit.get("lower")) == lo and float(limit.get("upper")) == hi, name


def test_ready_pose_is_arm_stretched_along_x():
    t = load_description().dh_forward(np.zeros(9))
    assert t[:3, 3] == pytest.approx([0.6034, 0.0, 0.1902], abs=1e-12)


def test_model_with_gripper_has_ten_joints():
    model = build_model(load_description(), include_gripper=True)
    assert model.nq == 10 and model.names[-1] == "gripper"
    assert model.existFrame("camera_link")


def test_committed_urdf_is_not_stale():
    assert urdf_main(["--check"]) == 0, "committed URDF is stale: run generate_urdf"


def test_stale_urdf_is_detected(tmp_path, raw):
    assert urdf_main(["--out-dir", str(tmp_path)]) == 0
    assert urdf_main(["--check", "--out-dir", str(tmp_path)]) == 0
    edited = _mutate(raw, lambda d: d["arm"]["joints"][0].update(upper="140 deg"))
    yml = tmp_path / "edited.yaml"
    yml.write_text(yaml.safe_dump(edited))
    assert urdf_main(["--check", "--out-dir", str(tmp_path), "--description", str(yml)]) == 1


# -- write_description_copy: a changed copy for -p description_file:= ----------------------

def test_a_changed_copy_is_written_checked_and_never_over_its_source(tmp_path):
    from hyperarm_description.model import write_description_copy

    src = tmp_path / "robot.yaml"
    src.write_text(default_description_path().read_text())
    before = src.read_text()

    def move_camera(data: dict) -> None:
        data["camera"]["xyz"] = [0.31, 0.01, 0.59]

    out = write_description_copy(src, tmp_path / "copy.yaml", move_camera, "# header\n")
    assert out.read_text().startswith("# header\n")
    assert load_description(out, "arm").camera.xyz == (0.31, 0.01, 0.59)
    assert src.read_text() == before                      # the source is untouched
    with pytest.raises(DescriptionError, match="refusing to overwrite"):
        write_description_copy(src, src, move_camera, "")
    assert src.read_text() == before

    def break_it(data: dict) -> None:
        data["camera"]["xyz"] = [0.3, "far"]

    bad = tmp_path / "bad.yaml"
    with pytest.raises(DescriptionError, match="the changed description is not valid: camera"):
        write_description_copy(src, bad, break_it, "")
    assert not bad.exists()                               # nothing written
