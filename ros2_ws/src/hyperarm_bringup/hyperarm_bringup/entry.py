"""Console-script entry points of the bring-up nodes (see hyperarm_description.launcher)."""
from hyperarm_description.launcher import lazy_main

viewer = lazy_main("hyperarm_bringup.viewer_node")
