"""hyperarm_description: the single source of truth for the hyperarm robot.

Import-light: importing the package imports nothing else; the names below are loaded from
:mod:`hyperarm_description.model` (numpy and PyYAML) on first use. The pinocchio model
builder lives in :mod:`hyperarm_description.pinocchio_model`.
"""
from __future__ import annotations

from typing import Any

__all__ = [
    "VARIANTS", "CameraSpec", "CapsuleSpec", "DescriptionError", "DHRow", "GripperSpec", "JointSpec",
    "LinkSpec", "RailSpec", "RobotDescription", "ServoSpec", "default_description_path",
    "load_description", "parse_angle",
]


def __getattr__(name: str) -> Any:  # PEP 562: ``from hyperarm_description import X``
    if name in __all__:
        from . import model

        return getattr(model, name)
    raise AttributeError(f"module 'hyperarm_description' has no attribute {name!r}")
