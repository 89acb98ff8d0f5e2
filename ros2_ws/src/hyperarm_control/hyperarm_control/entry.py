"""Console-script entry points of the controller nodes (see hyperarm_description.launcher):
a signal while they import their libraries is a quiet exit 0."""
from hyperarm_description.launcher import lazy_main

arm_controller = lazy_main("hyperarm_control.arm_controller_node")
