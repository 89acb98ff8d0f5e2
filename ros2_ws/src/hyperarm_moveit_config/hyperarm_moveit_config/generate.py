"""MoveIt 2 (Jazzy) configuration of hyperarm, generated from the robot description (no ROS,
no MoveIt needed to generate it).

From ``hyperarm.yaml`` (a :class:`~hyperarm_description.model.RobotDescription` per variant)
and its generated URDF (``hyperarm_description.urdf``), for each variant in
``config/<variant>/``:

- ``hyperarm.srdf``: the planning groups ``arm`` (chain base_link -> tool0: joint1..joint9)
  and, on rail_arm, ``rail_arm`` (chain world -> tool0: the rail and the arm), ``gripper``
  (the gripper joint) as the end effector on tool0, the group states ``ready`` (q = 0, the
  contract's ready pose) and ``open``/``closed`` (the gripper's limits), and the disabled
  collision pairs (:mod:`hyperarm_moveit_config.collision_matrix`: Adjacent, Always, Never
  over ``samples`` random configurations of our collision capsules);
- ``joint_limits.yaml``: velocity and acceleration limits of every joint (MoveIt's
  ``robot_description_planning``); position limits come from the URDF;
- ``kinematics.yaml``: MoveIt's KDL plugin for the planning groups;
- ``moveit_controllers.yaml``: ``arm_controller`` (FollowJointTrajectory) and
  ``gripper_controller`` (GripperCommand) for MoveIt's simple controller manager;

and ``launch/move_group.launch.py``, which starts move_group with them on the robot.

The files are committed (like the URDFs); ``generate_moveit_config --check`` (and a test)
fails if they differ from what this module generates now. Regenerate with
``generate_moveit_config`` after editing the YAML (docs/moveit.md).
"""
from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from importlib import resources
from pathlib import Path
from pprint import pformat
from typing import TYPE_CHECKING

import yaml

from hyperarm_description import contract
from hyperarm_description.contract import DEFAULT_NAMESPACE
from hyperarm_description.model import VARIANTS, RobotDescription, load_description
from hyperarm_description.urdf import generate_urdf

if TYPE_CHECKING:  # the collision matrix needs pinocchio and coal: imported when used
    from .collision_matrix import CollisionMatrix

__all__ = ["ROBOT_NAME", "ARM_GROUP", "RAIL_GROUP", "GRIPPER_GROUP", "ARM_CONTROLLER",
           "GRIPPER_CONTROLLER", "CONFIG_FILES", "LAUNCH_FILE", "SAMPLES", "SEED",
           "config_paths", "generate_srdf", "generate_joint_limits", "generate_kinematics",
           "generate_controllers", "generate_launch", "generate_moveit_config", "package_dir",
           "main"]

ROBOT_NAME = "hyperarm"
ARM_GROUP, RAIL_GROUP, GRIPPER_GROUP = "arm", "rail_arm", "gripper"
READY_STATE, OPEN_STATE, CLOSED_STATE = "ready", "open", "closed"
# The controllers of issue 26 (hyperarm_control): their action servers, in move_group's
# namespace, are <controller>/<action_ns>, from the contract.
ARM_CONTROLLER, ARM_ACTION_NS = contract.ARM_TRAJECTORY_ACTION.split("/")
GRIPPER_CONTROLLER, GRIPPER_ACTION_NS = contract.GRIPPER_ACTION.split("/")
KDL_PLUGIN = "kdl_kinematics_plugin/KDLKinematicsPlugin"
#: KDL's time per IK request (s): the Setup Assistant's 0.005 s is short for 9-10 joints
KDL_TIMEOUT = 0.05
KDL_SEARCH_RESOLUTION = 0.005
#: MoveIt's default scaling of the limits (what the Setup Assistant writes): plans run at
#: 10 % of the velocity and acceleration limits unless a request asks for more
DEFAULT_SCALING = 0.1
#: random configurations and seed of the disabled-collision computation
SAMPLES, SEED = 10000, 0
#: the generated files of each variant, by role, under config/<variant>/
CONFIG_FILES = {"srdf": "hyperarm.srdf", "joint_limits": "joint_limits.yaml",
                "kinematics": "kinematics.yaml", "controllers": "moveit_controllers.yaml"}
LAUNCH_FILE = "launch/move_group.launch.py"


def config_paths(variant: str) -> dict[str, str]:
    """Role -> path of a variant's generated file, relative to the package (and its share)."""
    return {role: f"config/{variant}/{name}" for role, name in CONFIG_FILES.items()}


def _header(desc: RobotDescription, what: str) -> str:
    src = Path(desc.source).name if desc.source else "the robot description"
    return (f"GENERATED from {src} by hyperarm_moveit_config.generate (variant "
            f"{desc.variant}): {what}. Do not edit: edit the YAML and run "
            f"`generate_moveit_config`.")


def _num(x: float) -> str:
    return "0" if abs(x) < 1e-15 else repr(float(x))


def _groups(desc: RobotDescription) -> list[tuple[str, str, str]]:
    """(group, chain base, chain tip) of the kinematic planning groups."""
    groups = [(ARM_GROUP, desc.base_frame, desc.tool_frame)]
    if desc.rail:
        groups.append((RAIL_GROUP, desc.root_frame, desc.tool_frame))
    return groups


def generate_srdf(desc: RobotDescription, urdf_text: str, matrix: CollisionMatrix) -> str:
    """The SRDF of ``desc`` (robot name as in its URDF) with ``matrix``'s disabled pairs."""
    robot = ET.Element("robot", name=ET.fromstring(urdf_text).get("name"))
    robot.append(ET.Comment(f" {_header(desc, 'the semantic description for MoveIt')} "))
    robot.append(ET.Comment(" GROUPS: the kinematic chains to plan for, and the gripper "))
    for name, base, tip in _groups(desc):
        ET.SubElement(ET.SubElement(robot, "group", name=name), "chain", base_link=base,
                      tip_link=tip)
    ET.SubElement(ET.SubElement(robot, "group", name=GRIPPER_GROUP), "joint",
                  name=desc.gripper.name)
    robot.append(ET.Comment(" GROUP STATES: ready = every joint at 0 (the arm stretched along "
                            "base x; the rail centred), the gripper at its limits "))
    for name, _, _ in _groups(desc):
        state = ET.SubElement(robot, "group_state", name=READY_STATE, group=name)
        joints = desc.kinematic_joint_names if name == RAIL_GROUP else desc.arm_joint_names
        for joint in joints:
            ET.SubElement(state, "joint", name=joint, value="0")
    g = desc.gripper
    for name, value in ((OPEN_STATE, g.upper), (CLOSED_STATE, g.lower)):
        ET.SubElement(ET.SubElement(robot, "group_state", name=name, group=GRIPPER_GROUP),
                      "joint", name=g.name, value=_num(value))
    robot.append(ET.Comment(" END EFFECTOR: the gripper, on tool0 "))
    ET.SubElement(robot, "end_effector", name=GRIPPER_GROUP, parent_link=desc.tool_frame,
                  group=GRIPPER_GROUP, parent_group=ARM_GROUP)
    robot.append(ET.Comment(
        f" DISABLE COLLISIONS: from the collision capsules (hyperarm_ik.collision) over "
        f"{matrix.samples} random configurations within the joint limits (seed "
        f"{matrix.seed}): {matrix.summary()}. Always = in contact in at least "
        f"{matrix.always_fraction:.0%} of them (the count in a comment) "))
    for p in matrix.disabled():
        ET.SubElement(robot, "disable_collisions", link1=p.links[0], link2=p.links[1],
                      reason=p.reason)
        if p.contacts:
            robot.append(ET.Comment(f" in contact in {p.contacts} of {matrix.samples} "))
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _yaml(desc: RobotDescription, what: str, comments: list[str], data: dict) -> str:
    lines = [_header(desc, what), *comments]
    head = "".join(f"# {line}\n" for line in lines)
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=False)


def generate_joint_limits(desc: RobotDescription) -> str:
    """joint_limits.yaml: every joint's velocity and acceleration limits."""
    limits = {}
    if desc.rail:
        limits[desc.rail.name] = (desc.rail.velocity, desc.rail.acceleration)
    for j in desc.joints:
        limits[j.name] = (j.velocity, j.acceleration)
    limits[desc.gripper.name] = (desc.gripper.velocity, None)
    data = {"default_velocity_scaling_factor": DEFAULT_SCALING,
            "default_acceleration_scaling_factor": DEFAULT_SCALING,
            "joint_limits": {
                name: {"has_velocity_limits": True, "max_velocity": float(v),
                       "has_acceleration_limits": a is not None,
                       **({"max_acceleration": float(a)} if a is not None else {})}
                for name, (v, a) in limits.items()}}
    return _yaml(desc, "MoveIt's joint limits (robot_description_planning)", [
        "Velocity (rad/s; rail m/s) and acceleration (rad/s^2; rail m/s^2) limits of the",
        "description; position limits come from the URDF. The description gives the gripper",
        "no acceleration limit: MoveIt's time parameterization refuses a gripper-group",
        "trajectory without one (drive the gripper through gripper_controller instead).",
        f"Plans use {DEFAULT_SCALING:g} x the limits unless a request scales them up "
        "(the Setup Assistant's default)."], data)


def generate_kinematics(desc: RobotDescription) -> str:
    """kinematics.yaml: MoveIt's KDL plugin for each kinematic planning group."""
    data = {name: {"kinematics_solver": KDL_PLUGIN,
                   "kinematics_solver_search_resolution": KDL_SEARCH_RESOLUTION,
                   "kinematics_solver_timeout": KDL_TIMEOUT}
            for name, _, _ in _groups(desc)}
    return _yaml(desc, "MoveIt's IK plugin per planning group (robot_description_kinematics)", [
        "KDL is MoveIt's generic numerical IK (RViz goals, Cartesian paths). It is not",
        "hyperarm's own IK: that is the ROS service solve_ik (hyperarm_ik ik_service, the",
        "paper's solvers, work-cell collisions), which MoveIt does not call."], data)


def generate_controllers(desc: RobotDescription) -> str:
    """moveit_controllers.yaml: arm_controller and gripper_controller for MoveIt's simple
    controller manager."""
    data = {"moveit_controller_manager":
            "moveit_simple_controller_manager/MoveItSimpleControllerManager",
            "moveit_simple_controller_manager": {
                "controller_names": [ARM_CONTROLLER, GRIPPER_CONTROLLER],
                ARM_CONTROLLER: {"type": "FollowJointTrajectory", "action_ns": ARM_ACTION_NS,
                                 "default": True, "joints": desc.kinematic_joint_names},
                GRIPPER_CONTROLLER: {"type": "GripperCommand",
                                     "action_ns": GRIPPER_ACTION_NS, "default": True,
                                     "joints": [desc.gripper.name]}}}
    comments = ["MoveIt's controllers: the action servers of hyperarm_control in move_group's",
                "namespace (/hyperarm by default): arm_controller/follow_joint_trajectory and",
                "gripper_controller/gripper_command. GripperCommand's position is the gripper",
                "joint's value (rad); max_effort 0 = the gripper's default grip effort."]
    if desc.rail:
        comments += ["arm_controller takes exactly its joints (rail included): execute",
                     f"plans of the {RAIL_GROUP} group (an {ARM_GROUP}-group plan names no rail)."]
    return _yaml(desc, "MoveIt's trajectory execution (moveit_simple_controller_manager)",
                 comments, data)


_LAUNCH = '''"""move_group (MoveIt 2 Jazzy) for hyperarm, with the generated configuration.

GENERATED by hyperarm_moveit_config.generate: do not edit (run `generate_moveit_config`).

On the robot, with MoveIt from apt (docs/moveit.md), next to the bring-up (drivers,
robot_state_publisher, arm_controller, gripper_controller):
    ros2 launch hyperarm_moveit_config move_group.launch.py
    ros2 launch hyperarm_moveit_config move_group.launch.py variant:=rail_arm
move_group runs in the namespace of the hyperarm nodes (/hyperarm): it reads joint_states
there and sends its trajectories to arm_controller/follow_joint_trajectory and
gripper_controller/gripper_command there.
"""
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from moveit_configs_utils import MoveItConfigsBuilder

ROBOT_NAME = {robot}
PACKAGE = "hyperarm_moveit_config"
NAMESPACE = {namespace}
#: the URDF of each variant, in hyperarm_description's share directory
URDF = {urdf}
#: the generated files of each variant, in this package's share directory
CONFIG = {config}


def _move_group(context):
    variant = LaunchConfiguration("variant").perform(context)
    files = CONFIG[variant]
    urdf = Path(get_package_share_directory("hyperarm_description")) / URDF[variant]
    config = (
        MoveItConfigsBuilder(ROBOT_NAME, package_name=PACKAGE)
        .robot_description(file_path=str(urdf))
        .robot_description_semantic(file_path=files["srdf"])
        .robot_description_kinematics(file_path=files["kinematics"])
        .joint_limits(file_path=files["joint_limits"])
        # hyperarm's controllers are always running nodes: nothing for MoveIt to switch
        .trajectory_execution(file_path=files["controllers"], moveit_manage_controllers=False)
        .planning_pipelines(pipelines=["ompl"])   # moveit_configs_utils' default OMPL set-up
        .to_moveit_configs()
    )
    return [Node(package="moveit_ros_move_group", executable="move_group",
                 namespace=LaunchConfiguration("namespace"), output="screen",
                 parameters=[config.to_dict(), {{"publish_robot_description_semantic": True}}])]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("variant", default_value="arm", choices=list(CONFIG),
                              description="robot variant: arm or rail_arm"),
        DeclareLaunchArgument("namespace", default_value=NAMESPACE,
                              description="namespace of the hyperarm nodes"),
        OpaqueFunction(function=_move_group),
    ])
'''


def generate_launch() -> str:
    """launch/move_group.launch.py (the same for every variant: ``variant`` is an argument)."""
    def literal(value, indent: int = 0) -> str:   # a Python literal, at most 92 columns
        return pformat(value, width=92 - indent, sort_dicts=False).replace(
            "\n", "\n" + " " * indent).replace("'", '"')
    return _LAUNCH.format(robot=literal(ROBOT_NAME),
                          namespace=literal(DEFAULT_NAMESPACE.strip("/")),
                          urdf=literal({v: f"urdf/hyperarm_{v}.urdf" for v in VARIANTS}, 6),
                          config=literal({v: config_paths(v) for v in VARIANTS}, 9))


def generate_moveit_config(description: str | Path | None = None, samples: int = SAMPLES,
                           seed: int = SEED) -> tuple[dict[str, str], dict[str, CollisionMatrix]]:
    """Every generated file (path relative to the package -> text) of every variant, and
    each variant's collision matrix (for its figures)."""
    from .collision_matrix import compute_collision_matrix
    files: dict[str, str] = {LAUNCH_FILE: generate_launch()}
    matrices = {}
    for variant in VARIANTS:
        desc = load_description(description, variant)
        urdf = generate_urdf(desc)
        matrix = compute_collision_matrix(desc, urdf, samples, seed)
        paths = config_paths(variant)
        files[paths["srdf"]] = generate_srdf(desc, urdf, matrix)
        files[paths["joint_limits"]] = generate_joint_limits(desc)
        files[paths["kinematics"]] = generate_kinematics(desc)
        files[paths["controllers"]] = generate_controllers(desc)
        matrices[variant] = matrix
    return files, matrices


def package_dir() -> Path:
    """The folder the generated files are committed in (this Python package's folder)."""
    return Path(str(resources.files("hyperarm_moveit_config")))


def main(argv: list[str] | None = None) -> int:
    """Console script ``generate_moveit_config``: write (or --check) the configuration."""
    ap = argparse.ArgumentParser(
        prog="generate_moveit_config",
        description="Write hyperarm's MoveIt 2 configuration (SRDF, joint limits, kinematics, "
                    "controllers, move_group launch file), generated from the robot "
                    "description (docs/moveit.md).")
    ap.add_argument("--description", help="robot YAML (default: the packaged hyperarm.yaml)")
    ap.add_argument("--out-dir", help="where to write (default: the package's own folder)")
    ap.add_argument("--check", action="store_true",
                    help="write nothing; exit 1 if a committed file differs from the output")
    args = ap.parse_args(argv)
    out = Path(args.out_dir) if args.out_dir else package_dir()
    files, matrices = generate_moveit_config(args.description)
    for variant, m in matrices.items():
        print(f"{variant}: {len(m.links)} links with collision geometry, {m.summary()} "
              f"({m.samples} samples, seed {m.seed})")
        for a, b in m.ready_contacts:
            print(f"{variant}: warning: {a} and {b} touch at q = 0 (ready is in collision)",
                  file=sys.stderr)
    stale = []
    for rel, text in files.items():
        target = out / rel
        current = target.read_text(encoding="utf-8") if target.exists() else None
        if current == text:
            continue
        if args.check:
            stale.append(str(target))
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text, encoding="utf-8")
            print(f"wrote {target}")
    if stale:
        print("stale MoveIt configuration (run generate_moveit_config): " + ", ".join(stale),
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
