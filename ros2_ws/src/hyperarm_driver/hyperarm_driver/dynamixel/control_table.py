"""Dynamixel Protocol 2.0 control tables and the supported servo models (no ROS).

X-series and MX-series (2.0 firmware) servos share the control-table layout below (the
addresses used here are identical on XM430-W350/-W210, XH430-W350, XM540-W270, MX-64(2.0)
and MX-106(2.0)); the models differ in units and limits, kept in :data:`MODELS`.
Figures are ROBOTIS e-Manual catalogue values; the torque constant is stall torque / stall
current at 12 V, a linear approximation (N·m/A).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

__all__ = [
    "Register",
    "REGISTERS",
    "EEPROM_END",
    "TABLE_SIZE",
    "INDIRECT_ADDRESS_1",
    "INDIRECT_DATA_1",
    "INDIRECT_COUNT",
    "BUS_WATCHDOG_UNIT",
    "BUS_WATCHDOG_FIRMWARE",
    "OperatingMode",
    "HARDWARE_ERROR_BITS",
    "decode_hardware_error",
    "ModelSpec",
    "MODELS",
    "model_by_name",
    "model_by_number",
    "TICKS_PER_REV",
    "CENTER_TICK",
    "RAD_PER_TICK",
    "VELOCITY_UNIT_RPM",
    "RADPS_PER_VELOCITY_UNIT",
]


@dataclass(frozen=True)
class Register:
    """One control-table item: byte address, size (1, 2 or 4) and signedness."""

    name: str
    address: int
    size: int
    signed: bool = False
    eeprom: bool = False


def _regs(*items: Register) -> Mapping[str, Register]:
    return MappingProxyType({r.name: r for r in items})


REGISTERS: Mapping[str, Register] = _regs(
    Register("model_number", 0, 2, eeprom=True),
    Register("model_information", 2, 4, eeprom=True),
    Register("firmware_version", 6, 1, eeprom=True),
    Register("id", 7, 1, eeprom=True),
    Register("baud_rate", 8, 1, eeprom=True),
    Register("return_delay_time", 9, 1, eeprom=True),
    Register("drive_mode", 10, 1, eeprom=True),
    Register("operating_mode", 11, 1, eeprom=True),
    Register("homing_offset", 20, 4, signed=True, eeprom=True),
    Register("temperature_limit", 31, 1, eeprom=True),
    Register("max_voltage_limit", 32, 2, eeprom=True),
    Register("min_voltage_limit", 34, 2, eeprom=True),
    Register("current_limit", 38, 2, eeprom=True),
    Register("velocity_limit", 44, 4, eeprom=True),
    Register("max_position_limit", 48, 4, eeprom=True),
    Register("min_position_limit", 52, 4, eeprom=True),
    Register("shutdown", 63, 1, eeprom=True),
    Register("torque_enable", 64, 1),
    Register("led", 65, 1),
    Register("status_return_level", 68, 1),
    Register("hardware_error_status", 70, 1),
    Register("bus_watchdog", 98, 1, signed=True),
    Register("goal_current", 102, 2, signed=True),
    Register("goal_velocity", 104, 4, signed=True),
    Register("profile_acceleration", 108, 4),
    Register("profile_velocity", 112, 4),
    Register("goal_position", 116, 4, signed=True),
    Register("moving", 122, 1),
    Register("present_current", 126, 2, signed=True),
    Register("present_velocity", 128, 4, signed=True),
    Register("present_position", 132, 4, signed=True),
    Register("present_input_voltage", 144, 2),
    Register("present_temperature", 146, 1),
)

EEPROM_END = 64          # addresses below are EEPROM (writable with torque off only)
TABLE_SIZE = 256         # bytes emulated/addressable here (indirect 1..28 included)
INDIRECT_ADDRESS_1 = 168  # Indirect Address n at 168 + 2(n-1), 2 bytes each
INDIRECT_DATA_1 = 224     # Indirect Data n at 224 + (n-1), 1 byte each
INDIRECT_COUNT = 28
BUS_WATCHDOG_UNIT = 0.02  # s per unit of Bus Watchdog (98); 1..127 arm it, -1 = tripped
BUS_WATCHDOG_FIRMWARE = 38  # first firmware version with Bus Watchdog (98)


class OperatingMode:
    """Values of the Operating Mode register (11)."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16

    BY_NAME: Mapping[str, int] = MappingProxyType({
        "current": 0, "velocity": 1, "position": 3, "extended_position": 4,
        "current_based_position": 5, "pwm": 16})
    NAMES: Mapping[int, str] = MappingProxyType({v: k for k, v in BY_NAME.items()})


# Hardware Error Status (70) bit -> name.
HARDWARE_ERROR_BITS: Mapping[int, str] = MappingProxyType({
    0: "input_voltage", 2: "overheating", 3: "motor_encoder", 4: "electrical_shock",
    5: "overload"})


def decode_hardware_error(value: int) -> list[str]:
    """Names of the bits set in a Hardware Error Status value (unknown bits as ``bit<n>``)."""
    return [HARDWARE_ERROR_BITS.get(b, f"bit{b}") for b in range(8) if value >> b & 1]


TICKS_PER_REV = 4096
CENTER_TICK = 2048
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
VELOCITY_UNIT_RPM = 0.229
RADPS_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class ModelSpec:
    """A servo model: number, current unit (A per LSB), limits, torque constant (N·m/A).

    ``current_limit`` and ``velocity_limit`` are the factory register values (raw units);
    ``modes`` the operating modes it supports.
    """

    name: str
    number: int
    current_unit: float
    current_limit: int
    velocity_limit: int
    torque_constant: float
    stall_torque: float
    modes: tuple[int, ...] = (0, 1, 3, 4, 5, 16)

    @property
    def max_current(self) -> float:
        """Factory current limit, A."""
        return self.current_limit * self.current_unit

    @property
    def max_torque(self) -> float:
        """Torque at the factory current limit, N·m."""
        return self.max_current * self.torque_constant


MODELS: Mapping[str, ModelSpec] = MappingProxyType({m.name: m for m in (
    ModelSpec("XM430-W350", 1020, 2.69e-3, 1193, 265, 4.1 / 2.3, 4.1),
    ModelSpec("XM430-W210", 1030, 2.69e-3, 1193, 330, 3.0 / 2.3, 3.0),
    ModelSpec("XH430-W350", 1010, 1.34e-3, 648, 210, 3.4 / 1.3, 3.4),
    ModelSpec("XM540-W270", 1120, 2.69e-3, 2047, 167, 10.6 / 4.4, 10.6),
    ModelSpec("MX-64", 311, 3.36e-3, 1941, 285, 6.0 / 4.1, 6.0),
    ModelSpec("MX-106", 321, 3.36e-3, 2047, 210, 8.4 / 5.2, 8.4),
)})
_BY_NUMBER = {m.number: m for m in MODELS.values()}


def model_by_name(name: str) -> ModelSpec:
    """The model called ``name`` (``"MX-64"`` means the 2.0 firmware); ValueError if unknown."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unsupported Dynamixel model {name!r} "
                         f"(supported: {', '.join(MODELS)})") from None


def model_by_number(number: int) -> ModelSpec | None:
    """The model with this model number, or None if not in the table."""
    return _BY_NUMBER.get(number)
