"""Mock driver core: simulated joints (and, later, the simulated work cell). No ROS."""
