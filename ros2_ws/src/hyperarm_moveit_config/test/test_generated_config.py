"""The generated MoveIt configuration (hyperarm_moveit_config.generate): the committed files
equal what the generator writes now, they parse, and they name only the URDF's joints and
links, with the description's limits. Nothing here needs MoveIt or ROS; the freshness check
needs pinocchio and coal (the collision matrix)."""
from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
import yaml

from hyperarm_description.model import VARIANTS, load_description
from hyperarm_description.urdf import generate_urdf
from hyperarm_moveit_config import generate
from hyperarm_moveit_config.generate import (ARM_CONTROLLER, GRIPPER_CONTROLLER, config_paths,
                                             main, package_dir)

pytestmark = pytest.mark.core

REASONS = {"Adjacent", "Always", "Never"}


@pytest.fixture(scope="module")
def generated():
    """What the generator writes now: (files, collision matrices), computed once."""
    return generate.generate_moveit_config()


def _srdf(variant: str) -> ET.Element:
    return ET.parse(package_dir() / config_paths(variant)["srdf"]).getroot()


def _yaml(variant: str, role: str):
    return yaml.safe_load((package_dir() / config_paths(variant)[role]).read_text())


class Urdf:
    """The generated URDF of a variant: links, joints, the kinematic tree."""

    def __init__(self, variant: str) -> None:
        self.desc = load_description(variant=variant)
        self.root = ET.fromstring(generate_urdf(self.desc))
        self.links = {link.get("name") for link in self.root.findall("link")}
        self.joints = {j.get("name"): j for j in self.root.findall("joint")}
        self.parent_joint = {j.find("child").get("link"): j for j in self.joints.values()}

    def chain(self, base: str, tip: str) -> list[str]:
        """Names of the movable joints from ``base`` to ``tip`` (tip must descend from base)."""
        out, link = [], tip
        while link != base:
            joint = self.parent_joint.get(link)
            assert joint is not None, f"{tip} does not descend from {base}"
            if joint.get("type") != "fixed":
                out.append(joint.get("name"))
            link = joint.find("parent").get("link")
        return out[::-1]

    def limits(self, joint: str) -> tuple[float, float]:
        lim = self.joints[joint].find("limit")
        return float(lim.get("lower")), float(lim.get("upper"))


def test_committed_files_are_what_the_generator_writes_now(generated, monkeypatch, capsys):
    monkeypatch.setattr(generate, "generate_moveit_config", lambda *a, **k: generated)
    assert main(["--check"]) == 0, "committed MoveIt configuration is stale: run " \
                                   "generate_moveit_config"
    out = capsys.readouterr().out
    assert "arm: 11 links with collision geometry" in out, out


def test_a_stale_or_missing_file_is_detected(generated, monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(generate, "generate_moveit_config", lambda *a, **k: generated)
    assert main(["--check", "--out-dir", str(tmp_path)]) == 1          # nothing written yet
    assert main(["--out-dir", str(tmp_path)]) == 0
    assert main(["--check", "--out-dir", str(tmp_path)]) == 0
    srdf = tmp_path / config_paths("arm")["srdf"]
    srdf.write_text(srdf.read_text().replace('reason="Never"', 'reason="Adjacent"', 1))
    assert main(["--check", "--out-dir", str(tmp_path)]) == 1
    assert str(srdf) in capsys.readouterr().err


def test_every_variant_has_its_files_and_the_launch_file():
    for variant in VARIANTS:
        for rel in config_paths(variant).values():
            assert (package_dir() / rel).is_file(), rel
    assert (package_dir() / generate.LAUNCH_FILE).is_file()


@pytest.mark.parametrize("variant", VARIANTS)
def test_srdf_groups_are_the_urdf_chains(variant):
    urdf, srdf = Urdf(variant), _srdf(variant)
    assert srdf.get("name") == urdf.root.get("name")   # MoveIt pairs SRDF and URDF by name
    groups = {g.get("name"): g for g in srdf.findall("group")}
    desc = urdf.desc
    expected = {"arm": desc.arm_joint_names, "gripper": [desc.gripper.name]}
    if variant == "rail_arm":
        expected["rail_arm"] = [desc.rail.name] + desc.arm_joint_names
    assert set(groups) == set(expected)
    for name, group in groups.items():
        chains = group.findall("chain")
        if chains:
            (chain,) = chains
            assert {chain.get("base_link"), chain.get("tip_link")} <= urdf.links
            assert urdf.chain(chain.get("base_link"), chain.get("tip_link")) == expected[name]
            assert chain.get("tip_link") == "tool0"
        else:
            assert [j.get("name") for j in group.findall("joint")] == expected[name]
    assert urdf.chain("base_link", "tool0") == [f"joint{i}" for i in range(1, 10)]


@pytest.mark.parametrize("variant", VARIANTS)
def test_srdf_states_and_end_effector_name_real_joints_within_limits(variant):
    urdf, srdf = Urdf(variant), _srdf(variant)
    groups = {g.get("name") for g in srdf.findall("group")}
    states = {}
    for state in srdf.findall("group_state"):
        assert state.get("group") in groups
        values = {j.get("name"): float(j.get("value")) for j in state.findall("joint")}
        for joint, value in values.items():
            lo, hi = urdf.limits(joint)
            assert lo <= value <= hi, (state.get("name"), joint, value)
        states[(state.get("name"), state.get("group"))] = values
    desc = urdf.desc
    assert states[("ready", "arm")] == dict.fromkeys(desc.arm_joint_names, 0.0)
    assert states[("open", "gripper")] == {"gripper": desc.gripper.upper}
    assert states[("closed", "gripper")] == {"gripper": desc.gripper.lower}
    if variant == "rail_arm":
        assert states[("ready", "rail_arm")] == dict.fromkeys(desc.kinematic_joint_names, 0.0)
    (eef,) = srdf.findall("end_effector")
    assert (eef.get("parent_link"), eef.get("group"), eef.get("parent_group")) == \
        ("tool0", "gripper", "arm")
    # the gripper group's links hang below tool0, which ends the parent group's chain
    assert urdf.joints["gripper"].find("parent").get("link") == "tool0"


@pytest.mark.parametrize("variant", VARIANTS)
def test_disabled_pairs_name_links_with_collision_geometry_once(variant):
    urdf, srdf = Urdf(variant), _srdf(variant)
    shaped = {link.get("name") for link in urdf.root.findall("link")
              if link.find("collision") is not None}
    pairs = [(d.get("link1"), d.get("link2"), d.get("reason"))
             for d in srdf.findall("disable_collisions")]
    assert pairs
    for a, b, reason in pairs:
        assert a in shaped and b in shaped and a < b and reason in REASONS, (a, b, reason)
    assert len({(a, b) for a, b, _ in pairs}) == len(pairs)


@pytest.mark.parametrize("variant", VARIANTS)
def test_joint_limits_are_the_descriptions(variant):
    desc = load_description(variant=variant)
    data = _yaml(variant, "joint_limits")
    assert 0.0 < data["default_velocity_scaling_factor"] <= 1.0
    assert 0.0 < data["default_acceleration_scaling_factor"] <= 1.0
    limits = data["joint_limits"]
    assert list(limits) == desc.all_joint_names
    expected = {j.name: (j.velocity, j.acceleration) for j in desc.joints}
    if desc.rail:
        expected[desc.rail.name] = (desc.rail.velocity, desc.rail.acceleration)
    for name, (v, a) in expected.items():
        assert limits[name] == {"has_velocity_limits": True, "max_velocity": v,
                                "has_acceleration_limits": True, "max_acceleration": a}
    # the description has no gripper acceleration: none is made up
    assert limits["gripper"] == {"has_velocity_limits": True,
                                 "max_velocity": desc.gripper.velocity,
                                 "has_acceleration_limits": False}
    urdf = Urdf(variant)
    for name in limits:
        assert urdf.joints[name].get("type") in ("revolute", "prismatic")


@pytest.mark.parametrize("variant", VARIANTS)
def test_kinematics_cover_the_chain_groups(variant):
    data = _yaml(variant, "kinematics")
    chain_groups = {g.get("name") for g in _srdf(variant).findall("group")
                    if g.find("chain") is not None}
    assert set(data) == chain_groups
    for entry in data.values():
        assert entry["kinematics_solver"] == "kdl_kinematics_plugin/KDLKinematicsPlugin"
        assert entry["kinematics_solver_timeout"] > 0
        assert entry["kinematics_solver_search_resolution"] > 0


@pytest.mark.parametrize("variant", VARIANTS)
def test_controllers_are_arm_and_gripper_controller(variant):
    desc = load_description(variant=variant)
    data = _yaml(variant, "controllers")
    assert data["moveit_controller_manager"] == \
        "moveit_simple_controller_manager/MoveItSimpleControllerManager"
    manager = data["moveit_simple_controller_manager"]
    assert manager["controller_names"] == [ARM_CONTROLLER, GRIPPER_CONTROLLER]
    assert manager[ARM_CONTROLLER] == {
        "type": "FollowJointTrajectory", "action_ns": "follow_joint_trajectory",
        "default": True, "joints": desc.kinematic_joint_names}
    assert manager[GRIPPER_CONTROLLER] == {
        "type": "GripperCommand", "action_ns": "gripper_command", "default": True,
        "joints": [desc.gripper.name]}
    urdf = Urdf(variant)
    assert set(desc.all_joint_names) <= set(urdf.joints)
    assert (variant == "rail_arm") == ("rail" in manager[ARM_CONTROLLER]["joints"])


