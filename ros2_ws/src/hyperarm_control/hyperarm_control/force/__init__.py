"""The hybrid position/force controller's ROS-free core (docs/force.md).

- ``law``: the control law (stiffness, selection, feed-forward, damping, gravity, null
  space, saturation) and its two outputs (``torque``, ``position``);
- ``wrench``: the sensorless wrench estimate (damped (J^T)^+, filter, covariance, tare);
- ``calibration``: per-servo torque scale/offset from static poses, and its YAML file.
"""
from .calibration import TorqueCalibration, fit_calibration, load_calibration, save_calibration
from .errors import CalibrationError, ForceConfigError, ForceError, InvalidGoalError, StateError
from .law import OUTPUTS, Command, HybridGoal, HybridLaw, LawConfig, Payload, make_goal
from .wrench import EstimatorConfig, WrenchEstimate, WrenchEstimator, to_tool

__all__ = ["TorqueCalibration", "fit_calibration", "load_calibration", "save_calibration",
           "CalibrationError", "ForceConfigError", "ForceError", "InvalidGoalError",
           "StateError", "OUTPUTS", "Command", "HybridGoal", "HybridLaw", "LawConfig",
           "Payload", "make_goal", "EstimatorConfig", "WrenchEstimate", "WrenchEstimator",
           "to_tool"]
