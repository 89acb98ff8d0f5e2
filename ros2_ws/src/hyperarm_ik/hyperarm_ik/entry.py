"""Console-script entry points of the IK nodes (see hyperarm_description.launcher)."""
from hyperarm_description.launcher import lazy_main

fk_node = lazy_main("hyperarm_ik.fk_node")
tf_publisher = lazy_main("hyperarm_ik.tf_publisher_node")
ik_service = lazy_main("hyperarm_ik.ik_service_node")
