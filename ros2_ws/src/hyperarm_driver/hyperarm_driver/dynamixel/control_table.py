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
    "INDIRECT_ADDRESS_29",
    "INDIRECT_DATA_29",
    "BAUD_RATES",
    "Item",
    "control_items",
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
    "ACCELERATION_UNIT_RPM2",
    "RADPS2_PER_ACCELERATION_UNIT",
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
TABLE_SIZE = 662         # bytes of the control table (Indirect Data 56 ends at 661)
INDIRECT_ADDRESS_1 = 168  # Indirect Address n at 168 + 2(n-1), 2 bytes each (n = 1..28)
INDIRECT_DATA_1 = 224     # Indirect Data n at 224 + (n-1), 1 byte each (n = 1..28)
INDIRECT_COUNT = 28       # per block; a second block of 28 follows:
INDIRECT_ADDRESS_29 = 578  # Indirect Address n at 578 + 2(n-29) (n = 29..56)
INDIRECT_DATA_29 = 634     # Indirect Data n at 634 + (n-29)
BAUD_RATES = MappingProxyType({0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000,
                               5: 3_000_000, 6: 4_000_000, 7: 4_500_000})  # Baud Rate (8)
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


@dataclass(frozen=True)
class Item:
    """One item of a model's control table as the e-Manual lists it: address, size, access
    (``R`` or ``RW``) and the range a write must fall in (signed values as signed)."""

    name: str
    address: int
    size: int
    access: str
    lo: int = 0
    hi: int = 0
    signed: bool = False


def control_items(model: "ModelSpec") -> tuple[Item, ...]:
    """The control table of ``model`` (X series, or MX(2.0) series: ``model.series``).

    From the ROBOTIS e-Manual control tables (XM430-W350, MX-64(2.0), firmware v45): same
    addresses on both series; MX(2.0) has no Startup Configuration (60), no Backup Ready
    (147) and no PWM items differ. Ranges that depend on another item (Goal Position within
    the Position Limits, Goal Current within Current Limit, ...) are checked by the emulator
    at write time (Data Limit Error) and listed here with the widest range.
    """
    x = model.series == "X"
    items = [
        Item("model_number", 0, 2, "R"), Item("model_information", 2, 4, "R"),
        Item("firmware_version", 6, 1, "R"), Item("id", 7, 1, "RW", 0, 252),
        Item("baud_rate", 8, 1, "RW", 0, 7), Item("return_delay_time", 9, 1, "RW", 0, 254),
        Item("drive_mode", 10, 1, "RW", 0, 13 if x else 5),
        Item("operating_mode", 11, 1, "RW", 0, 16),
        Item("secondary_id", 12, 1, "RW", 0, 255), Item("protocol_type", 13, 1, "RW", 1, 2),
        Item("homing_offset", 20, 4, "RW", -1_044_479, 1_044_479, True),
        Item("moving_threshold", 24, 4, "RW", 0, 1023),
        Item("temperature_limit", 31, 1, "RW", 0, 100),
        Item("max_voltage_limit", 32, 2, "RW", 95, 160),
        Item("min_voltage_limit", 34, 2, "RW", 95, 160),
        Item("pwm_limit", 36, 2, "RW", 0, 885),
        Item("current_limit", 38, 2, "RW", 0, model.current_limit),
        Item("velocity_limit", 44, 4, "RW", 0, 1023),
        Item("max_position_limit", 48, 4, "RW", 0, 4095),
        Item("min_position_limit", 52, 4, "RW", 0, 4095),
        Item("shutdown", 63, 1, "RW", 0, 255),
        Item("torque_enable", 64, 1, "RW", 0, 1), Item("led", 65, 1, "RW", 0, 1),
        Item("status_return_level", 68, 1, "RW", 0, 2),
        Item("registered_instruction", 69, 1, "R"), Item("hardware_error_status", 70, 1, "R"),
        Item("velocity_i_gain", 76, 2, "RW", 0, 16383),
        Item("velocity_p_gain", 78, 2, "RW", 0, 16383),
        Item("position_d_gain", 80, 2, "RW", 0, 16383),
        Item("position_i_gain", 82, 2, "RW", 0, 16383),
        Item("position_p_gain", 84, 2, "RW", 0, 16383),
        Item("feedforward_2nd_gain", 88, 2, "RW", 0, 16383),
        Item("feedforward_1st_gain", 90, 2, "RW", 0, 16383),
        Item("bus_watchdog", 98, 1, "RW", 0, 127, True),
        Item("goal_pwm", 100, 2, "RW", -885, 885, True),
        Item("goal_current", 102, 2, "RW", -model.current_limit, model.current_limit, True),
        Item("goal_velocity", 104, 4, "RW", -1023, 1023, True),
        Item("profile_acceleration", 108, 4, "RW", 0, 32767),
        Item("profile_velocity", 112, 4, "RW", 0, 32767),
        Item("goal_position", 116, 4, "RW", -1_048_575, 1_048_575, True),
        Item("realtime_tick", 120, 2, "R"), Item("moving", 122, 1, "R"),
        Item("moving_status", 123, 1, "R"), Item("present_pwm", 124, 2, "R"),
        Item("present_current", 126, 2, "R"), Item("present_velocity", 128, 4, "R"),
        Item("present_position", 132, 4, "R"), Item("velocity_trajectory", 136, 4, "R"),
        Item("position_trajectory", 140, 4, "R"),
        Item("present_input_voltage", 144, 2, "R"), Item("present_temperature", 146, 1, "R"),
    ]
    if x:
        items += [Item("startup_configuration", 60, 1, "RW", 0, 3),
                  Item("backup_ready", 147, 1, "R")]
    for n in range(56):
        a = (INDIRECT_ADDRESS_1 + 2 * n) if n < 28 else (INDIRECT_ADDRESS_29 + 2 * (n - 28))
        d = (INDIRECT_DATA_1 + n) if n < 28 else (INDIRECT_DATA_29 + n - 28)
        items.append(Item(f"indirect_address_{n + 1}", a, 2, "RW", 64, TABLE_SIZE - 1))
        items.append(Item(f"indirect_data_{n + 1}", d, 1, "RW", 0, 255))
    return tuple(sorted(items, key=lambda i: i.address))


TICKS_PER_REV = 4096
CENTER_TICK = 2048
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
VELOCITY_UNIT_RPM = 0.229
RADPS_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0
# Profile Acceleration (108) unit, rev/min² (e-Manual, X series, velocity-based profile)
ACCELERATION_UNIT_RPM2 = 214.577
RADPS2_PER_ACCELERATION_UNIT = ACCELERATION_UNIT_RPM2 * 2.0 * math.pi / 3600.0


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
    series: str = "X"        # "X" or "MX" (2.0 firmware): instruction set, control table

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
    ModelSpec("MX-64", 311, 3.36e-3, 1941, 285, 6.0 / 4.1, 6.0, series="MX"),
    ModelSpec("MX-106", 321, 3.36e-3, 2047, 210, 8.4 / 5.2, 8.4, series="MX"),
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
