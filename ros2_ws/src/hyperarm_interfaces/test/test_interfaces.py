"""The generated interfaces carry the fields of the contract (docs/architecture.md)."""
from __future__ import annotations

import pytest

pytestmark = pytest.mark.core


def _fields(cls) -> dict[str, str]:
    return dict(cls.get_fields_and_field_types())


def test_solve_ik_contract():
    from hyperarm_interfaces.srv import SolveIK

    req, res = _fields(SolveIK.Request), _fields(SolveIK.Response)
    assert req == {"target": "geometry_msgs/PoseStamped", "seed": "sensor_msgs/JointState",
                   "solver": "string", "position_only": "boolean",
                   "position_tolerance": "double", "orientation_tolerance": "double",
                   "timeout": "double", "collisions": "uint8", "block_held": "boolean"}
    assert res == {"success": "boolean", "solution": "sensor_msgs/JointState",
                   "position_error": "double", "orientation_error": "double",
                   "iterations": "uint32", "solve_time": "double", "message": "string",
                   "contacts": "sequence<string>"}
    assert (SolveIK.Request.COLLISIONS_DEFAULT, SolveIK.Request.COLLISIONS_IGNORE,
            SolveIK.Request.COLLISIONS_CHECK, SolveIK.Request.COLLISIONS_AVOID) == (0, 1, 2, 3)


def test_hybrid_goal_and_detections():
    from hyperarm_interfaces.msg import Detections, HybridGoal

    assert _fields(HybridGoal) == {"header": "std_msgs/Header", "pose": "geometry_msgs/Pose",
                                   "stiffness": "double[6]", "force_controlled": "boolean[6]",
                                   "wrench": "geometry_msgs/Wrench"}
    assert _fields(Detections) == {"header": "std_msgs/Header", "names": "sequence<string>",
                                   "poses": "sequence<geometry_msgs/Pose>",
                                   "covariances": "sequence<double>"}
    goal = HybridGoal()
    assert len(goal.stiffness) == 6 and len(goal.force_controlled) == 6


def test_run_task_and_reboot():
    from hyperarm_interfaces.action import RunTask
    from hyperarm_interfaces.srv import Reboot

    assert set(_fields(RunTask.Goal)) == {"task", "object_names", "object_poses"}
    assert set(_fields(RunTask.Feedback)) == {"stage", "step_type", "phase", "stage_index",
                                              "stage_count", "progress", "step_progress",
                                              "waypoint", "force", "depth"}
    assert set(_fields(RunTask.Result)) == {"success", "message", "failure_kind", "stage_names",
                                            "stage_durations", "total_time", "metric_names",
                                            "metric_values"}
    assert _fields(Reboot.Request) == {"joints": "sequence<string>"}
    assert set(_fields(Reboot.Response)) == {"success", "rebooted", "message"}
