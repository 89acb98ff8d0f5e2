"""Console-script entry points of the controller nodes (see hyperarm_description.launcher):
a signal while they import their libraries is a quiet exit 0."""
from hyperarm_description.launcher import lazy_main

arm_controller = lazy_main("hyperarm_control.arm_controller_node")
hybrid_force = lazy_main("hyperarm_control.hybrid_force_node")
hybrid_force_calibrate = lazy_main("hyperarm_control.force_calibration_node")
host_compensation = lazy_main("hyperarm_control.host_compensation_node")
gripper_controller = lazy_main("hyperarm_control.gripper_controller_node")
