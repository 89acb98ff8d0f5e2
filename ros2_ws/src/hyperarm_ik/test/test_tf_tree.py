"""Core tier: the TF tree (hyperarm_ik.tf_tree) against the URDF and our FK.

Every frame composed from the root through the tree's transforms equals, within 1e-9:
pinocchio's frame placement, ``Kinematics.forward`` (tool0), the description's own DH
chain (``frame_poses``, no pinocchio) and the committed URDF evaluated joint by joint as
robot_state_publisher does (origin, then the motion about or along the axis), for random
configurations of both variants. The edges are exactly the URDF's joints.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_description.joints import JointStateError
from hyperarm_description.model import load_description
from hyperarm_description.pinocchio_model import build_model
from hyperarm_description.urdf import urdf_path
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.tf_tree import TfTree, check_joint_state, compose

pytestmark = pytest.mark.core

VARIANTS = ("arm", "rail_arm")
TOL = 1e-9
SAMPLES = 300


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    def rot(axis, a):
        c, s = math.cos(a), math.sin(a)
        i, j = [k for k in range(3) if k != axis]
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m if axis != 1 else m.T     # Ry: the sign of its sines is the other way
    return rot(2, y) @ rot(1, p) @ rot(0, r)


def _axis_angle(axis: np.ndarray, a: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * (k @ k)


def urdf_joints(text: str) -> dict[str, dict]:
    """joint name -> type, parent, child, origin (4x4), axis of a URDF text."""
    out = {}
    for j in ET.fromstring(text).iter("joint"):
        origin = j.find("origin")
        xyz = [float(v) for v in origin.get("xyz").split()]
        rpy = [float(v) for v in origin.get("rpy").split()]
        t = np.eye(4)
        t[:3, :3], t[:3, 3] = _rpy(*rpy), xyz
        axis = j.find("axis")
        out[j.get("name")] = {
            "type": j.get("type"), "parent": j.find("parent").get("link"),
            "child": j.find("child").get("link"), "origin": t,
            "axis": np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None
            else None}
    return out


def urdf_transform(joint: dict, q: float) -> np.ndarray:
    """The joint's transform as robot_state_publisher computes it (KDL: origin * motion)."""
    motion = np.eye(4)
    if joint["type"] in ("revolute", "continuous"):
        motion[:3, :3] = _axis_angle(joint["axis"], q)
    elif joint["type"] == "prismatic":
        motion[:3, 3] = joint["axis"] * q
    return joint["origin"] @ motion


def _max_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)))


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_edges_are_the_urdf_joints(variant):
    tree = TfTree(load_description(variant=variant))
    joints = urdf_joints(urdf_path(variant).read_text())
    assert {e.joint: (e.parent, e.child, e.fixed) for e in tree.edges} == \
        {n: (j["parent"], j["child"], j["type"] == "fixed") for n, j in joints.items()}
    links = {link.get("name") for link in ET.fromstring(urdf_path(variant).read_text())
             .iter("link")}
    assert set(tree.frames) == links and len(tree.frames) == len(links)
    want = {"base_link", "camera_link", "tool0", "gripper_finger",
            *(f"link{i}" for i in range(1, 10))}
    if variant == "rail_arm":
        want |= {"world", "rail_carriage"}
    assert set(tree.frames) == want
    assert tree.root == ("world" if variant == "rail_arm" else "base_link")
    fixed = {(t.parent, t.child) for t in tree.static_transforms()}
    assert fixed == ({(tree.root, "camera_link"), ("link9", "tool0")}
                     | ({("rail_carriage", "base_link")} if variant == "rail_arm" else set()))
    assert list(tree.joint_names) == load_description(variant=variant).all_joint_names


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_frame_matches_our_fk_within_1e_9(variant):
    desc = load_description(variant=variant)
    tree = TfTree(desc)
    kin = Kinematics(desc)
    full = build_model(desc, include_gripper=True)
    data = full.createData()
    joints = urdf_joints(urdf_path(variant).read_text())
    statics = tree.static_transforms()
    rng = np.random.default_rng(26)
    worst = {"pinocchio": 0.0, "Kinematics": 0.0, "DH": 0.0, "URDF": 0.0}
    names = list(tree.joint_names)
    for _ in range(SAMPLES):
        q = kin.random_configuration(rng)
        grip = rng.uniform(desc.gripper.lower, desc.gripper.upper)
        values = [*q, grip]
        poses = compose(tree.transforms(tree.check(names, values)) + statics, tree.root)
        assert set(poses) == set(tree.frames)
        pin.framesForwardKinematics(full, data, np.array(values))
        for f in tree.frames:
            worst["pinocchio"] = max(worst["pinocchio"], _max_diff(
                poses[f], data.oMf[full.getFrameId(f)].homogeneous))
        worst["Kinematics"] = max(worst["Kinematics"], _max_diff(poses["tool0"],
                                                                 kin.forward(q)))
        base = np.linalg.inv(poses["base_link"])
        for f, pose in desc.frame_poses(q[-9:]).items():
            worst["DH"] = max(worst["DH"], _max_diff(base @ poses[f], pose))
        by_name = dict(zip(names, values))
        for name, j in joints.items():
            t = np.linalg.inv(poses[j["parent"]]) @ poses[j["child"]]
            worst["URDF"] = max(worst["URDF"], _max_diff(
                t, urdf_transform(j, by_name.get(name, 0.0))))
    assert max(worst.values()) < TOL, worst


def test_a_joints_transform_depends_on_its_own_position_only():
    """One driver's message (the rail alone, the arm without the rail) gives the same
    transforms as the whole state: each edge is its joint's own."""
    tree = TfTree(load_description(variant="rail_arm"))
    rng = np.random.default_rng(3)
    values = dict(zip(tree.joint_names, rng.uniform(-1.0, 1.0, len(tree.joint_names))))
    whole = {(t.parent, t.child): t.matrix for t in tree.transforms(values)}
    rail = tree.transforms({"rail": values["rail"]})
    arm = tree.transforms({n: v for n, v in values.items() if n != "rail"})
    assert [(t.parent, t.child) for t in rail] == [("world", "rail_carriage")]
    for t in rail + arm:
        assert np.array_equal(t.matrix, whole[(t.parent, t.child)])
    assert len(rail) + len(arm) == len(whole)


def test_quaternions_are_unit_and_the_matrix_rotation():
    tree = TfTree(load_description())
    rng = np.random.default_rng(5)
    values = dict(zip(tree.joint_names, rng.uniform(-2.5, 2.5, len(tree.joint_names))))
    for t in tree.transforms(values) + tree.static_transforms():
        x, y, z, w = t.quaternion
        assert abs(math.sqrt(x * x + y * y + z * z + w * w) - 1.0) < 1e-12
        r = pin.Quaternion(w, x, y, z).toRotationMatrix()
        assert _max_diff(r, t.matrix[:3, :3]) < 1e-12


@pytest.mark.parametrize("names, position, velocity, effort, match", [
    ([], [], [], [], "no joint names"),
    (["joint1", "joint2"], [0.1], [], [], "position: 1 values for 2"),
    (["joint1"], [math.nan], [], [], "non-finite position"),
    (["joint1"], [math.inf], [], [], "non-finite position"),
    (["joint1", "elbow"], [0.1, 0.2], [], [], "unknown joint"),
    (["rail"], [0.1], [], [], "unknown joint"),                 # no rail on arm
    (["joint1", "joint1"], [0.1, 0.2], [], [], "duplicate"),
    (["joint1", "joint2"], [0.1, 0.2], [0.0], [], "velocity: 1 values for 2"),
    (["joint1", "joint2"], [0.1, 0.2], [], [0.0, 0.0, 0.0], "effort: 3 values for 2"),
    (["joint1"], [0.1], [math.nan], [], "non-finite velocity"),
    (["joint1"], [0.1], [0.0], [math.nan], "non-finite effort"),
])
def test_a_bad_joint_state_is_rejected_whole(names, position, velocity, effort, match):
    tree = TfTree(load_description())
    with pytest.raises(JointStateError, match=match):
        tree.check(names, position, velocity, effort)


def test_a_good_joint_state_gives_its_positions():
    known = ("joint1", "joint2", "gripper")
    assert check_joint_state(["gripper", "joint1"], [0.5, -1.0], [], [1.0, 2.0], known) == \
        {"gripper": 0.5, "joint1": -1.0}
