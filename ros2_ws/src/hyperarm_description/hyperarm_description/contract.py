"""The hyperarm interface contract as plain constants (no ROS import).

Every node takes its topic, service and frame names from here, so the drivers, the mock and
the higher-level nodes cannot drift apart. Names are relative: nodes run in the namespace
``/hyperarm`` by default (``DEFAULT_NAMESPACE``), except ``/diagnostics`` and ``/clock``,
which are absolute by ROS convention. See docs/architecture.md for the full contract.
"""
from __future__ import annotations

DEFAULT_NAMESPACE = "/hyperarm"

# Frames
WORLD_FRAME = "world"
BASE_FRAME = "base_link"
TOOL_FRAME = "tool0"
RAIL_FRAME = "rail_carriage"
CAMERA_FRAME = "camera_link"

# Topics (relative to the namespace)
JOINT_STATES = "joint_states"          # sensor_msgs/JointState, every driver, its own joints
JOINT_COMMAND = "joint_command"        # sensor_msgs/JointState, setpoints by joint name
TOOL_POSE = "tool_pose"                # geometry_msgs/PoseStamped, fk_node
HYBRID_GOAL = "hybrid_goal"            # hyperarm_interfaces/HybridGoal -> hybrid_force node
EE_WRENCH = "ee_wrench"                # geometry_msgs/WrenchStamped, estimated at tool0
EE_WRENCH_BASE = "ee_wrench_base"      # geometry_msgs/WrenchStamped, same estimate in base_link
TOOL_WRENCH_TRUTH = "debug/tool_wrench_truth"  # mock only: true wrench at tool0 (WrenchStamped)
CONTACTS_TRUTH = "debug/contacts"      # mock only: per-link contacts (diagnostic_msgs/DiagnosticArray)
DETECTIONS = "detections"              # hyperarm_interfaces/Detections, in camera_link
DETECTIONS_TRUTH = "debug/detections_truth"  # mock only: ground truth, same type
DIAGNOSTICS = "/diagnostics"           # diagnostic_msgs/DiagnosticArray (absolute)
CLOCK = "/clock"                       # rosgraph_msgs/Clock, mock with sim time (absolute)
# TF (issue 26): robot_state_publisher on the robot, else hyperarm_ik's tf_publisher. /tf and
# /tf_static are absolute (tf2's names); robot_description is relative, as
# robot_state_publisher publishes it.
TF = "/tf"                             # tf2_msgs/TFMessage: moving joints, per joint_states
TF_STATIC = "/tf_static"               # tf2_msgs/TFMessage: every fixed joint, once (latched)
ROBOT_DESCRIPTION = "robot_description"  # std_msgs/String: the URDF (latched)
# Host motion (issue 15). On the arm variant, `world` exists only while host_pose is given.
HOST_POSE = "host_pose"                # geometry_msgs/PoseStamped: base_link in world
BASE_REACTION = "base_reaction"        # geometry_msgs/WrenchStamped: arm on its mount, base_link
HOST_COMP_GOAL = "host_compensation/goal"  # geometry_msgs/PoseStamped: tool0 goal in world
TOOL_POSE_TRUTH = "debug/tool_pose_truth"  # mock only: true tool0 in world (PoseStamped)

# Services (relative to the namespace)
SOLVE_IK = "solve_ik"                  # hyperarm_interfaces/SolveIK
SET_TORQUE = "set_torque"              # std_srvs/SetBool: true = torque on
REBOOT = "reboot"                      # hyperarm_interfaces/Reboot
HOLD = "hold"                          # std_srvs/Trigger: stop where you are
RAIL_HOME = "rail/home"                # std_srvs/Trigger (rail drivers)
# On rail_arm every service has one owner: the arm driver serves SET_TORQUE/HOLD/REBOOT for
# the arm and gripper; the rail driver serves its own under rail/.
RAIL_SET_TORQUE = "rail/set_torque"    # std_srvs/SetBool (rail drivers)
RAIL_HOLD = "rail/hold"                # std_srvs/Trigger (rail drivers)
# Hybrid force node. While it is enabled it is the only publisher of arm joint_command; the
# task node sends HYBRID_GOAL then, and joint_command only after disabling it.
HYBRID_ENABLE = "hybrid_force/enable"  # std_srvs/SetBool
HYBRID_TARE = "hybrid_force/tare"      # std_srvs/Trigger: capture the wrench estimate's bias
HYBRID_COMPLIANCE = "hybrid_force/compliance"  # std_srvs/SetBool: whole-arm compliance mode
# Host-motion compensation. While enabled it is the only publisher of arm joint_command.
HOST_COMP_ENABLE = "host_compensation/enable"  # std_srvs/SetBool: true = hold tool0 in world
# Mock only: its scripted host motion (parameter host_motion). true = start (ramped in),
# false = ramp out and stop at rest.
HOST_MOTION_ENABLE = "host_motion/enable"      # std_srvs/SetBool

# Actions (relative to the namespace)
RUN_TASK = "run_task"                  # hyperarm_interfaces/RunTask
# The ROS arm conventions (issue 26): joint_trajectory_controller's and
# gripper_action_controller's names, as moveit_controllers.yaml points at them.
ARM_CONTROLLER = "arm_controller"
ARM_TRAJECTORY_ACTION = "arm_controller/follow_joint_trajectory"  # control_msgs/FollowJointTrajectory
ARM_TRAJECTORY_TOPIC = "arm_controller/joint_trajectory"  # trajectory_msgs/JointTrajectory
GRIPPER_CONTROLLER = "gripper_controller"
GRIPPER_ACTION = "gripper_controller/gripper_command"  # control_msgs/GripperCommand

# QoS, as plain settings (hyperarm_description.qos builds rclpy profiles from them).
# Everything the robot acts on or reports is RELIABLE (a lost command or state is a bug, and
# reliable writers also match best-effort readers such as rviz); commands keep depth 1 (only
# the newest setpoint matters), states and detections a short history.
QOS = {
    JOINT_STATES: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    JOINT_COMMAND: {"reliability": "reliable", "durability": "volatile", "depth": 1},
    TOOL_POSE: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    HYBRID_GOAL: {"reliability": "reliable", "durability": "volatile", "depth": 1},
    EE_WRENCH: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    EE_WRENCH_BASE: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    DETECTIONS: {"reliability": "reliable", "durability": "volatile", "depth": 5},
    DETECTIONS_TRUTH: {"reliability": "reliable", "durability": "volatile", "depth": 5},
    TOOL_WRENCH_TRUTH: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    CONTACTS_TRUTH: {"reliability": "reliable", "durability": "volatile", "depth": 5},
    DIAGNOSTICS: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    HOST_POSE: {"reliability": "reliable", "durability": "volatile", "depth": 1},
    BASE_REACTION: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    HOST_COMP_GOAL: {"reliability": "reliable", "durability": "volatile", "depth": 1},
    TOOL_POSE_TRUTH: {"reliability": "reliable", "durability": "volatile", "depth": 10},
    # tf2's own profiles (tf2_ros DynamicBroadcasterQoS / StaticBroadcasterQoS), and
    # robot_state_publisher's for robot_description
    TF: {"reliability": "reliable", "durability": "volatile", "depth": 100},
    TF_STATIC: {"reliability": "reliable", "durability": "transient_local", "depth": 1},
    ROBOT_DESCRIPTION: {"reliability": "reliable", "durability": "transient_local", "depth": 1},
}

# Joint naming
ARM_JOINTS = tuple(f"joint{i}" for i in range(1, 10))
GRIPPER_JOINT = "gripper"
RAIL_JOINT = "rail"
