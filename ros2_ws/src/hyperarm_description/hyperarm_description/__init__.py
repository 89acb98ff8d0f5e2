"""hyperarm_description: the single source of truth for the hyperarm robot.

Import-light: ``load_description`` needs only numpy and PyYAML; the pinocchio model builder
lives in :mod:`hyperarm_description.pinocchio_model`.
"""
from .model import (VARIANTS, CameraSpec, CapsuleSpec, DescriptionError, DHRow, GripperSpec, JointSpec,
                    LinkSpec, RailSpec, RobotDescription, ServoSpec, default_description_path,
                    load_description, parse_angle)

__all__ = [
    "VARIANTS", "CameraSpec", "CapsuleSpec", "DescriptionError", "DHRow", "GripperSpec", "JointSpec",
    "LinkSpec", "RailSpec", "RobotDescription", "ServoSpec", "default_description_path",
    "load_description", "parse_angle",
]
