"""Per-joint servo configuration from the robot description, and unit conversions (no ROS).

Joint angle ``q`` (rad) and servo ticks: the servo angle is ``direction * q + zero_offset``
(rad, 0 = the servo's centre tick 2048), so ``ticks = 2048 + (direction*q + zero_offset) /
RAD_PER_TICK``. ``zero_offset`` is thus the servo angle at which the joint reads 0.
Velocities: raw unit 0.229 rev/min. Current: raw unit = the model's ``current_unit`` (A);
torque = current * torque constant (N·m/A, linear approximation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .control_table import (
    CENTER_TICK, RAD_PER_TICK, RADPS2_PER_ACCELERATION_UNIT, RADPS_PER_VELOCITY_UNIT, ModelSpec, OperatingMode, model_by_name)
from .errors import ConfigError

__all__ = ["JointServo", "BusConfig", "bus_config_from_description", "velocity_to_raw",
           "acceleration_to_raw"]


@dataclass(frozen=True)
class JointServo:
    """One joint's servo: ID, model, direction (+1/-1), zero offset (rad), limits.

    ``lower``/``upper`` (rad) are the joint limits; ``velocity`` (rad/s) the profile
    velocity; ``acceleration`` (rad/s²) the profile acceleration, ``None`` to leave the
    servo's register alone (the gripper: its closing is judged by stall); ``mode`` the operating mode used for position commands (``position`` or
    ``current_based_position``); ``hold_effort`` (N·m) the current limit used in
    current-based position mode when no effort is commanded (the gripper's grip torque);
    ``gripper`` marks the gripper's servo (``hold`` leaves a gripping gripper squeezing).
    """

    name: str
    id: int
    model: ModelSpec
    direction: int
    zero_offset: float
    lower: float
    upper: float
    velocity: float
    mode: str = "position"
    hold_effort: float | None = None
    gripper: bool = False
    acceleration: float | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.id <= 252:
            raise ConfigError(f"{self.name}: servo ID must be 0..252, got {self.id}")
        if self.direction not in (1, -1):
            raise ConfigError(f"{self.name}: direction must be 1 or -1, got {self.direction}")
        if not (math.isfinite(self.lower) and math.isfinite(self.upper)
                and self.lower < self.upper):
            raise ConfigError(f"{self.name}: bad limits [{self.lower}, {self.upper}]")
        if self.mode not in ("position", "current_based_position"):
            raise ConfigError(f"{self.name}: operating mode {self.mode!r} not supported by the "
                              "driver (position or current_based_position)")
        lo, hi = self.tick_limits
        if lo < 0 or hi > 4095:
            raise ConfigError(f"{self.name}: limits [{self.lower:.3f}, {self.upper:.3f}] rad "
                              f"with zero_offset {self.zero_offset:.3f} fall outside one servo "
                              f"turn (ticks {lo}..{hi})")
        if not (self.velocity > 0 and math.isfinite(self.velocity)):
            raise ConfigError(f"{self.name}: velocity must be > 0, got {self.velocity}")
        if self.acceleration is not None and not (
                self.acceleration > 0 and math.isfinite(self.acceleration)):
            raise ConfigError(f"{self.name}: acceleration must be > 0, got {self.acceleration}")

    # -- conversions -----------------------------------------------------------------------
    def rad_to_ticks_float(self, q: float) -> float:
        return CENTER_TICK + (self.direction * q + self.zero_offset) / RAD_PER_TICK

    def ticks_to_rad(self, ticks: float) -> float:
        return self.direction * ((ticks - CENTER_TICK) * RAD_PER_TICK - self.zero_offset)

    @property
    def tick_limits(self) -> tuple[int, int]:
        """(min, max) ticks whose angles lie inside [lower, upper] (written to the servo)."""
        a = self.rad_to_ticks_float(self.lower)
        b = self.rad_to_ticks_float(self.upper)
        lo, hi = min(a, b), max(a, b)
        # tolerate float noise of 1e-9 tick so an exact limit keeps its tick
        return math.ceil(lo - 1e-9), math.floor(hi + 1e-9)

    @property
    def effort_limit(self) -> float:
        """Largest torque the servo's factory current limit allows, N·m."""
        return self.model.max_torque

    @property
    def mode_value(self) -> int:
        return OperatingMode.BY_NAME[self.mode]


@dataclass(frozen=True)
class BusConfig:
    """All servos on the bus, in joint order (arm joints, then the gripper)."""

    joints: tuple[JointServo, ...]

    def __post_init__(self) -> None:
        ids = [j.id for j in self.joints]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"duplicate servo IDs: {ids}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ConfigError(f"duplicate joint names: {names}")
        if not self.joints:
            raise ConfigError("no servos configured")

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def ids(self) -> list[int]:
        return [j.id for j in self.joints]

    def index(self, name: str) -> int:
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise KeyError(name)

    # Vectorised conversions (arrays in joint order) --------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        return {
            "dir": np.array([j.direction for j in self.joints], dtype=float),
            "off": np.array([j.zero_offset for j in self.joints], dtype=float),
            "cur": np.array([j.model.current_unit for j in self.joints], dtype=float),
            "kt": np.array([j.model.torque_constant for j in self.joints], dtype=float),
        }


def velocity_to_raw(v: float) -> int:
    """rad/s -> Profile Velocity units (0.229 rev/min), at least 1 (0 would mean 'no limit')."""
    return max(1, int(round(v / RADPS_PER_VELOCITY_UNIT)))


def acceleration_to_raw(a: float) -> int:
    """rad/s² -> Profile Acceleration units (214.577 rev/min² ≈ 0.3745 rad/s²), at least 1
    (0 would mean 'no limit'), at most the register's 32767."""
    return min(32767, max(1, int(round(a / RADPS2_PER_ACCELERATION_UNIT))))


def bus_config_from_description(desc) -> BusConfig:  # type: ignore[no-untyped-def]
    """Build the bus configuration of the nine arm joints + gripper of a RobotDescription."""
    joints: list[JointServo] = []
    specs: Sequence = list(desc.joints) + [desc.gripper]
    for spec in specs:
        servo = spec.servo
        try:
            model = model_by_name(servo.model)
        except ValueError as exc:
            raise ConfigError(f"{spec.name}: {exc}") from exc
        is_gripper = spec is desc.gripper
        joints.append(JointServo(
            name=spec.name, id=servo.id, model=model, direction=servo.direction,
            zero_offset=servo.zero_offset, lower=spec.lower, upper=spec.upper,
            velocity=spec.velocity, mode=servo.operating_mode,
            acceleration=None if is_gripper else spec.acceleration,
            hold_effort=desc.gripper.grip_effort if is_gripper else None,
            gripper=is_gripper))
    return BusConfig(tuple(joints))
