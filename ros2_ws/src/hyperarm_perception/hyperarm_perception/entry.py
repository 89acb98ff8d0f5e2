"""Console-script entry points of the perception nodes (see hyperarm_description.launcher):
a signal while they import OpenCV and rclpy is a quiet exit 0."""
from hyperarm_description.launcher import lazy_main

marker_detector = lazy_main("hyperarm_perception.marker_detector_node")
usb_camera = lazy_main("hyperarm_perception.usb_camera_node")
mock_camera = lazy_main("hyperarm_perception.mock_camera_node")
calibrate_camera = lazy_main("hyperarm_perception.calibrate_camera")
