"""The control_msgs and tf2_msgs in use (ros2_ws/compat on the PyPI route, apt's on the robot)
carry the RIHS01 type hashes of Jazzy's releases, so that arm_controller's action and the TF
topics interoperate with MoveIt, RViz and ros2 CLI tools built against apt's packages.

The expected hashes were computed by rosidl_generator_type_description from the upstream
files themselves: ros-controls/control_msgs branch `jazzy` (5.8.0, commit f901df2) and
ros2/geometry2 branch `jazzy` (tf2_msgs/msg/TFMessage.msg), built in a scratch workspace
with this machine's Jazzy wheels. A field renamed, reordered or retyped in ros2_ws/compat
changes the hash and fails here."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

UPSTREAM = {
    ("control_msgs", "action", "FollowJointTrajectory"): {
        "control_msgs/action/FollowJointTrajectory":
            "RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6",
        "control_msgs/action/FollowJointTrajectory_Goal":
            "RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205",
        "control_msgs/action/FollowJointTrajectory_Result":
            "RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220",
        "control_msgs/action/FollowJointTrajectory_Feedback":
            "RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49",
        "control_msgs/action/FollowJointTrajectory_SendGoal":
            "RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f",
    },
    ("control_msgs", "action", "GripperCommand"): {
        "control_msgs/action/GripperCommand":
            "RIHS01_e17c0e644eccf14bea84a0a93e0977182872c2eb7873ca6694900059b46dbc84",
        "control_msgs/action/GripperCommand_Goal":
            "RIHS01_607d9f41eb241e1922e90f02125e87ae6bfb78f7f64a71dc92630263d01f8b6d",
        "control_msgs/action/GripperCommand_Result":
            "RIHS01_bf512d5aa6a0e4fe4d8be22b2ec4a1973c3d250fa1f65e47450322c25c45c0a0",
        "control_msgs/action/GripperCommand_Feedback":
            "RIHS01_8f7c520077bab528bb9161ee3b83c81eee1f8aecadb8922ce82c79d667a819c4",
    },
    ("control_msgs", "msg", "JointTolerance"): {
        "control_msgs/msg/JointTolerance":
            "RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648",
    },
    ("control_msgs", "msg", "JointComponentTolerance"): {
        "control_msgs/msg/JointComponentTolerance":
            "RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4",
    },
    ("control_msgs", "msg", "GripperCommand"): {
        "control_msgs/msg/GripperCommand":
            "RIHS01_57eb8f326c9889ca8bb34ead82cc94cc09bf6bc5c3b6c09546dca3a00b589890",
    },
    ("tf2_msgs", "msg", "TFMessage"): {
        "tf2_msgs/msg/TFMessage":
            "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    },
}


@pytest.mark.parametrize("key", sorted(UPSTREAM), ids=lambda k: "/".join(k))
def test_installed_type_hashes_equal_jazzys(key):
    from ament_index_python.packages import get_package_share_directory

    package, kind, name = key
    path = Path(get_package_share_directory(package)) / kind / f"{name}.json"
    described = {h["type_name"]: h["hash_string"]
                 for h in json.loads(path.read_text())["type_hashes"]}
    for type_name, expected in UPSTREAM[key].items():
        assert described.get(type_name) == expected, (type_name, path)


def test_the_python_types_carry_jazzys_fields_and_constants():
    """What users of the generated Python types read: the fields in order and the action's
    error codes (the hashes above cover the types; the constants do not enter a hash)."""
    from control_msgs.action import FollowJointTrajectory, GripperCommand
    from control_msgs.msg import JointComponentTolerance
    from tf2_msgs.msg import TFMessage

    result = FollowJointTrajectory.Result
    assert (result.SUCCESSFUL, result.INVALID_GOAL, result.INVALID_JOINTS,
            result.OLD_HEADER_TIMESTAMP, result.PATH_TOLERANCE_VIOLATED,
            result.GOAL_TOLERANCE_VIOLATED) == (0, -1, -2, -3, -4, -5)
    assert (JointComponentTolerance.X_AXIS, JointComponentTolerance.ROTATION) == (1, 5)
    goal = FollowJointTrajectory.Goal()
    assert [f for f in goal.get_fields_and_field_types()] == [
        "trajectory", "multi_dof_trajectory", "path_tolerance", "component_path_tolerance",
        "goal_tolerance", "component_goal_tolerance", "goal_time_tolerance"]
    assert list(GripperCommand.Result.get_fields_and_field_types()) == [
        "position", "effort", "stalled", "reached_goal"]
    assert list(TFMessage.get_fields_and_field_types()) == ["transforms"]
