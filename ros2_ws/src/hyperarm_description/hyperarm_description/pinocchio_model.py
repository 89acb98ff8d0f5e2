"""Pinocchio models of the robot, built from the generated URDF (no ROS needed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from .model import RobotDescription, load_description
from .urdf import generate_urdf

__all__ = ["build_model", "load_pinocchio_model"]


def build_model(desc: RobotDescription, include_gripper: bool = False) -> pin.Model:
    """Pinocchio model of ``desc``. Without the gripper, its joint is locked at 0.

    Joint order of ``q`` is the description's ``kinematic_joint_names`` (rail first for the
    rail variant), plus ``gripper`` last when ``include_gripper``. Frames include
    ``base_link``, ``tool0``, ``camera_link`` (and ``world``, ``rail_carriage`` for the rail).
    """
    model = pin.buildModelFromXML(generate_urdf(desc))
    model.name = f"{desc.name}_{desc.variant}"
    if not include_gripper:
        gid = model.getJointId(desc.gripper.name)
        model = pin.buildReducedModel(model, [gid], np.zeros(model.nq))
    expected = desc.kinematic_joint_names + ([desc.gripper.name] if include_gripper else [])
    names = list(model.names)[1:]
    if names != expected:  # a guard on the URDF generator, not on user input
        raise RuntimeError(f"pinocchio joint order {names} != description order {expected}")
    return model


def load_pinocchio_model(variant: str = "arm", path: str | Path | None = None,
                         include_gripper: bool = False) -> pin.Model:
    """Load the description (``path`` or the packaged YAML) and build its pinocchio model."""
    return build_model(load_description(path, variant), include_gripper=include_gripper)
