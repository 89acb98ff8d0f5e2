"""Console-script entry points of the driver nodes (see hyperarm_description.launcher)."""
from hyperarm_description.launcher import lazy_main

mock_driver = lazy_main("hyperarm_driver.mock_driver_node")
dynamixel_driver = lazy_main("hyperarm_driver.dynamixel_driver_node")
pmac_rail_driver = lazy_main("hyperarm_driver.pmac_rail_driver_node")
