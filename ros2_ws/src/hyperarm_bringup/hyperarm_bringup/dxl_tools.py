"""Dynamixel bus tools without ROS: scan, set-id, set-baud, read ticks, zero-offset calibration.

They open the serial port themselves with the ROBOTIS Dynamixel SDK (Protocol 2.0), so the
driver must not be running on that port. Units: baud in bit/s, angles in rad, positions in
ticks (0..4095, centre 2048).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from hyperarm_description.model import DescriptionError, default_description_path, \
    load_description, write_description_copy
from hyperarm_driver.dynamixel.control_table import BAUD_RATES, CENTER_TICK, RAD_PER_TICK, \
    REGISTERS, model_by_number

__all__ = ["BusToolError", "Found", "Bus", "scan", "set_id", "set_baud", "read_ticks",
           "zero_offsets", "write_calibrated_copy", "COMMON_BAUDS"]

#: The baud rates `scan` tries by default: the arm's 1 Mbit/s and the factory 57600 first.
COMMON_BAUDS = (1_000_000, 57_600, 115_200, 2_000_000, 3_000_000, 4_000_000, 9_600)


class BusToolError(Exception):
    """A bus tool failed: port, communication or a refused value (the message says which)."""


@dataclass(frozen=True)
class Found:
    """A servo that answered a ping."""

    id: int
    baud: int
    model_number: int
    firmware: int

    @property
    def model(self) -> str:
        spec = model_by_number(self.model_number)
        return spec.name if spec else f"unknown model {self.model_number}"


class Bus:
    """The SDK's PortHandler + Protocol 2.0 PacketHandler on one port at one baud rate."""

    def __init__(self, port: str, baud: int) -> None:
        import dynamixel_sdk as sdk

        if baud not in BAUD_RATES.values():
            raise BusToolError(f"baud {baud} is not a Dynamixel rate "
                               f"({', '.join(map(str, sorted(BAUD_RATES.values())))})")
        self._sdk = sdk
        self.port = sdk.PortHandler(port)
        self.packet = sdk.PacketHandler(2.0)
        try:
            opened = self.port.openPort() and self.port.setBaudRate(baud)
        except Exception as exc:  # the SDK raises serial's exceptions as they come
            raise BusToolError(f"cannot open {port}: {exc}") from None
        if not opened:
            raise BusToolError(f"cannot open {port} at {baud} baud")

    def close(self) -> None:
        self.port.closePort()

    def __enter__(self) -> "Bus":
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()

    def _check(self, result: int, error: int, what: str) -> None:
        if result != self._sdk.COMM_SUCCESS:
            raise BusToolError(f"{what}: {self.packet.getTxRxResult(result)}")
        if error:
            raise BusToolError(f"{what}: servo status error {self.packet.getRxPacketError(error)}")

    def ping_all(self, tries: int = 2) -> dict[int, tuple[int, int]]:
        """id -> (model number, firmware) of every servo answering a broadcast ping, over
        ``tries`` pings (a reply lost to noise or a busy host does not hide a servo)."""
        out: dict[int, tuple[int, int]] = {}
        for _ in range(tries):
            found, result = self.packet.broadcastPing(self.port)
            if result in (self._sdk.COMM_SUCCESS, self._sdk.COMM_RX_TIMEOUT):
                out.update({i: (v[0], v[1]) for i, v in found.items()})
            # else: garbled replies at a wrong baud rate: nobody here at this rate
        return out

    def _retry(self, call: Callable[[], tuple], tries: int = 3) -> tuple:
        """An SDK transfer, repeated up to ``tries`` times while no valid reply came."""
        for _ in range(tries - 1):
            out = call()
            if out[-2] == self._sdk.COMM_SUCCESS:
                return out
        return call()

    def read(self, dxl_id: int, register: str) -> int:
        reg = REGISTERS[register]
        reader = {1: self.packet.read1ByteTxRx, 2: self.packet.read2ByteTxRx,
                  4: self.packet.read4ByteTxRx}[reg.size]
        value, result, error = self._retry(lambda: reader(self.port, dxl_id, reg.address))
        self._check(result, error, f"read {register} of ID {dxl_id}")
        if reg.signed and value >= 1 << (8 * reg.size - 1):
            value -= 1 << (8 * reg.size)
        return value

    def write1(self, dxl_id: int, register: str, value: int) -> None:
        reg = REGISTERS[register]
        result, error = self.packet.write1ByteTxRx(self.port, dxl_id, reg.address, value)
        self._check(result, error, f"write {register} of ID {dxl_id}")


def scan(port: str, bauds: Iterable[int] = COMMON_BAUDS,
         ids: Sequence[int] | None = None) -> list[Found]:
    """Every servo on ``port`` over ``bauds`` (broadcast ping at each rate), by baud then ID;
    ``ids`` keeps only those IDs."""
    out: list[Found] = []
    for baud in bauds:
        with Bus(port, baud) as bus:
            for dxl_id, (model, fw) in sorted(bus.ping_all().items()):
                if ids is None or dxl_id in ids:
                    out.append(Found(dxl_id, baud, model, fw))
    return out


def _torque_off_or_refuse(bus: Bus, dxl_id: int) -> None:
    if bus.read(dxl_id, "torque_enable"):
        raise BusToolError(f"ID {dxl_id} has torque on: EEPROM (ID, baud rate) can only be "
                           "written with torque off (`hyperarm torque off`, or power-cycle)")


def set_id(port: str, baud: int, old: int, new: int) -> None:
    """Give servo ``old`` the ID ``new`` (1..252); refuses if ``new`` is taken."""
    if not 0 <= new <= 252 or not 0 <= old <= 252:
        raise BusToolError("IDs are 0..252")
    with Bus(port, baud) as bus:
        present = bus.ping_all()
        if old not in present:
            raise BusToolError(f"no servo with ID {old} answers at {baud} baud on {port}")
        if new in present:
            raise BusToolError(f"ID {new} is already taken on this bus")
        _torque_off_or_refuse(bus, old)
        try:
            bus.write1(old, "id", new)
        except BusToolError:
            pass  # the status reply may be lost while the ID changes: the ping below decides
        if new not in bus.ping_all():
            raise BusToolError(f"ID {old} was written but no servo answers as ID {new}")


def set_baud(port: str, baud: int, dxl_id: int, new_baud: int) -> None:
    """Set servo ``dxl_id`` (now at ``baud``) to ``new_baud`` and check it answers there."""
    index = {v: k for k, v in BAUD_RATES.items()}.get(new_baud)
    if index is None:
        raise BusToolError(f"{new_baud} is not a Dynamixel baud rate "
                           f"({', '.join(map(str, sorted(BAUD_RATES.values())))})")
    with Bus(port, baud) as bus:
        if dxl_id not in bus.ping_all():
            raise BusToolError(f"no servo with ID {dxl_id} answers at {baud} baud on {port}")
        _torque_off_or_refuse(bus, dxl_id)
        try:
            bus.write1(dxl_id, "baud_rate", index)
        except BusToolError:
            pass  # the reply may come at the new rate: the ping below decides
    with Bus(port, new_baud) as bus:
        if dxl_id not in bus.ping_all():
            raise BusToolError(f"ID {dxl_id} does not answer at {new_baud} baud after the change")


def read_ticks(port: str, baud: int, ids: Iterable[int]) -> dict[int, int]:
    """Present Position (ticks) of each servo ID."""
    with Bus(port, baud) as bus:
        return {i: bus.read(i, "present_position") for i in ids}


def zero_offsets(description: str | Path | None, variant: str, ticks: dict[int, int],
                 pose: dict[str, float] | None = None) -> dict[str, float]:
    """joint -> zero_offset (rad) such that the present ``ticks`` read as the calibration
    ``pose`` (joint -> rad, default 0 for every arm joint): servo angle at joint 0 =
    (ticks - 2048) * rad/tick - direction * q_pose."""
    desc = load_description(description, variant)
    pose = pose or {}
    unknown = set(pose) - {j.name for j in desc.joints}
    if unknown:
        raise BusToolError(f"calibration pose names unknown joints {sorted(unknown)}")
    out = {}
    for j in desc.joints:
        if j.servo.id not in ticks:
            raise BusToolError(f"no reading for {j.name} (ID {j.servo.id})")
        servo_angle = (ticks[j.servo.id] - CENTER_TICK) * RAD_PER_TICK
        out[j.name] = servo_angle - j.servo.direction * pose.get(j.name, 0.0)
    return out


def write_calibrated_copy(description: str | Path | None, offsets: dict[str, float],
                          out: str | Path, variant: str = "arm") -> Path:
    """A copy of the description YAML with ``zero_offset`` (rad, 6 decimals) set on the
    servos of ``offsets``, validated by loading it. The original is never modified."""
    if not all(math.isfinite(v) for v in offsets.values()):
        raise BusToolError("an offset is not finite")

    def edit(data: dict) -> None:
        for joint in data["arm"]["joints"]:
            if joint["name"] in offsets:
                joint["servo"]["zero_offset"] = round(float(offsets[joint["name"]]), 6)

    src = Path(description) if description else default_description_path()
    header = (f"# {src.name} with zero_offset from `hyperarm calibrate` (rad).\n"
              "# Use it with -p description_file:=<this file> on every node.\n")
    try:
        return write_description_copy(src, out, edit, header, variant)
    except DescriptionError as exc:
        raise BusToolError(str(exc)) from None
