"""Console-script entry points of the IK nodes (see hyperarm_description.launcher)."""
from hyperarm_description.launcher import lazy_main

fk_node = lazy_main("hyperarm_ik.fk_node")
tf_publisher = lazy_main("hyperarm_ik.tf_publisher_node")
ik_service = lazy_main("hyperarm_ik.ik_service_node")
hybrid_force = lazy_main("hyperarm_ik.hybrid_force_node")
hybrid_force_calibrate = lazy_main("hyperarm_ik.force_calibration_node")
host_compensation = lazy_main("hyperarm_ik.host_compensation_node")
