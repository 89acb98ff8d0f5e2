"""hyperarm_perception: camera images to object poses, without ROS (issue 27).

- :mod:`hyperarm_perception.markers`: the ArUco/AprilTag marker detector core on numpy
  images (pose in the camera frame, 6x6 covariance, counted rejections) and its YAML marker
  map.
- :mod:`hyperarm_perception.handeye`: eye-to-hand calibration of the fixed camera from arm
  poses (FK) and marker sightings, with residual statistics.
"""
