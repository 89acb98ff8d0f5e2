"""The Dynamixel bus on the official dynamixel-sdk (Protocol 2.0), in SI units (no ROS).

One cycle = one (fast) sync read of a 16-byte indirect block per servo (hardware error,
present current, velocity, position, input voltage, temperature, bus watchdog, torque
enable) + one sync write of a 6-byte indirect block (goal current, goal position). The indirect addresses are set up by
:meth:`DynamixelBus.configure`, so both transfers are single instructions.
Every SDK call is wrapped: port failures raise :class:`PortLostError`, failed transactions
:class:`CommError` (after ``retries`` retries).
"""
from __future__ import annotations

import logging
import math
import os
import termios
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from dynamixel_sdk import (COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler,
                           PortHandler)

from .config import BusConfig, acceleration_to_raw, velocity_to_raw
from .control_table import (BUS_WATCHDOG_FIRMWARE, BUS_WATCHDOG_UNIT, CENTER_TICK,
                            INDIRECT_ADDRESS_1, INDIRECT_DATA_1, RAD_PER_TICK,
                            RADPS_PER_VELOCITY_UNIT, REGISTERS, OperatingMode,
                            decode_hardware_error, model_by_number)
from .errors import CommError, PortLostError, PortOpenError, StartupError

__all__ = ["BusState", "BusStats", "DynamixelBus", "READ_BLOCK", "WRITE_BLOCK",
           "ftdi_latency_timer"]

_log = logging.getLogger(__name__)

# (register, size) laid out in indirect data, in this order
READ_BLOCK = ("hardware_error_status", "present_current", "present_velocity",
              "present_position", "present_input_voltage", "present_temperature",
              "bus_watchdog", "torque_enable")
WRITE_BLOCK = ("goal_current", "goal_position")


def _layout(names: Sequence[str]) -> tuple[list[int], dict[str, int], int]:
    """Indirect slot addresses (one per byte), offsets of each register, total length."""
    addrs: list[int] = []
    offsets: dict[str, int] = {}
    for name in names:
        r = REGISTERS[name]
        offsets[name] = len(addrs)
        addrs.extend(range(r.address, r.address + r.size))
    return addrs, offsets, len(addrs)


_READ_ADDRS, _READ_OFF, READ_LEN = _layout(READ_BLOCK)
_WRITE_ADDRS, _WRITE_OFF, WRITE_LEN = _layout(WRITE_BLOCK)
READ_DATA_ADDR = INDIRECT_DATA_1
WRITE_DATA_ADDR = INDIRECT_DATA_1 + READ_LEN
_PORT_ERRORS = (OSError, termios.error)  # serial.SerialException is an OSError


@dataclass
class BusState:
    """One sync read, arrays in joint order: rad, rad/s, N·m, A, V, °C, raw error bits,
    Bus Watchdog register (-1 = tripped), Torque Enable as the servo reports it (bool)."""

    stamp: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    current: np.ndarray
    hardware_error: np.ndarray
    voltage: np.ndarray
    temperature: np.ndarray
    ticks: np.ndarray
    bus_watchdog: np.ndarray
    torque: np.ndarray


@dataclass
class BusStats:
    """Transaction counters (since start) for diagnostics."""

    transactions: int = 0
    failures: int = 0
    retries: int = 0
    last_error: str = ""
    cycle_times: deque[float] = field(default_factory=lambda: deque(maxlen=10000))  # s


def ftdi_latency_timer(port: str, sysfs: str = "/sys/bus/usb-serial/devices") -> int | None:
    """The FTDI latency timer (ms) of ``port`` (symlinks followed), or None if the port is
    not a USB-serial device (pty, native UART) or the value cannot be read."""
    name = os.path.basename(os.path.realpath(port))
    try:
        return int(Path(sysfs, name, "latency_timer").read_text().strip())
    except (OSError, ValueError):
        return None


def _signed(value: int, size: int) -> int:
    bits = 8 * size
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


class DynamixelBus:
    """Servos of a :class:`BusConfig` on one port, through dynamixel-sdk."""

    def __init__(self, config: BusConfig, port: str, baud: int = 1_000_000, *,
                 fast_sync_read: bool = True, retries: int = 2) -> None:
        if PortHandler(port).getCFlagBaud(baud) <= 0:
            raise PortOpenError(f"baud rate {baud} not supported by dynamixel-sdk")
        self.config = config
        self.port_name = port
        self.baud = baud
        self.want_fast = fast_sync_read
        self.fast = False
        self.fast_error = ""     # why Fast Sync Read is not used (start-up check)
        self._fast_refused = ""  # the servos refused it once: not tried again at reconnects
        self.retries = retries
        self.stats = BusStats()
        self.port: PortHandler | None = None
        self.ph = PacketHandler(2.0)
        self._reader: GroupSyncRead | None = None
        self._writer: GroupSyncWrite | None = None
        a = config.arrays()
        self._dir, self._off, self._cur, self._kt = a["dir"], a["off"], a["cur"], a["kt"]
        self._lo_tick = np.array([j.tick_limits[0] for j in config.joints], dtype=np.int64)
        self._hi_tick = np.array([j.tick_limits[1] for j in config.joints], dtype=np.int64)
        self._climit = np.array([j.model.current_limit for j in config.joints], dtype=np.int64)
        # as written to each servo: every position-class command runs in current-based position
        self.modes = [OperatingMode.CURRENT_BASED_POSITION] * len(config.joints)
        self.torque = [False] * len(config.joints)   # as read from each servo every cycle
        # torque turned off by a mode switch that failed before turning it back on
        self.pending_on = [False] * len(config.joints)
        self.bus_watchdog = 0    # Bus Watchdog units armed in current mode (0 = off)
        self.has_watchdog = [False] * len(config.joints)   # firmware >= v38, see configure

    def set_bus_watchdog(self, seconds: float) -> None:
        """Arm the servos' Bus Watchdog (98) with ``seconds`` (rounded up to 20 ms, at most
        2.54 s; 0 = off) whenever a joint is switched to current mode: if the host goes
        silent (port lost, driver dead) such a servo stops pushing by itself."""
        if not 0.0 <= seconds < math.inf:
            raise ValueError(f"bus watchdog must be >= 0 s, got {seconds}")
        self.bus_watchdog = min(127, math.ceil(seconds / BUS_WATCHDOG_UNIT - 1e-9)) \
            if seconds > 0 else 0

    # -- port --------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self.port is not None

    def open(self) -> None:
        """Open the port at ``baud``; PortOpenError naming the port if impossible."""
        port = PortHandler(self.port_name)
        try:
            ok = port.setBaudRate(self.baud)    # opens the port at this rate (openPort()
            # would use the SDK's default, 1 Mbit/s, whatever ``baud`` says)
        except _PORT_ERRORS as exc:
            raise PortOpenError(f"cannot open Dynamixel port {self.port_name}: {exc}") from exc
        if not ok:
            raise PortOpenError(f"cannot open Dynamixel port {self.port_name} at {self.baud} baud")
        self.port = port
        self._reader = GroupSyncRead(port, self.ph, READ_DATA_ADDR, READ_LEN)
        for j in self.config.joints:
            self._reader.addParam(j.id)
        self._writer = GroupSyncWrite(port, self.ph, WRITE_DATA_ADDR, WRITE_LEN)
        for j in self.config.joints:
            self._writer.addParam(j.id, [0] * WRITE_LEN)

    def close(self) -> None:
        port, self.port = self.port, None
        self._reader = self._writer = None
        self.pending_on = [False] * len(self.config.joints)   # reconnect: torque off
        if port is not None:
            try:
                port.closePort()
            except _PORT_ERRORS:
                pass
        self.torque = [False] * len(self.config.joints)

    def resync(self) -> None:
        """Make the port usable again after a transaction was interrupted half-way (Ctrl-C
        raises KeyboardInterrupt inside the SDK, which then leaves its port flagged busy and
        every later call fails with "Port is in use!"): clear that flag, drop stale input."""
        if self.port is None:
            return
        self.port.is_using = False
        try:
            self.port.clearPort()
        except _PORT_ERRORS:
            pass

    def _call(self, fn: Callable, *args):  # type: ignore[no-untyped-def]
        if self.port is None:
            raise PortLostError(f"Dynamixel port {self.port_name} is not open")
        try:
            return fn(*args)
        except _PORT_ERRORS as exc:
            self.port.is_using = False
            self.close()
            raise PortLostError(f"Dynamixel port {self.port_name} lost: {exc}") from exc

    def _check(self, what: str, result: int, error: int = 0, *, hw_ok: bool = True) -> None:
        self.stats.transactions += 1
        if result != COMM_SUCCESS:
            self.stats.failures += 1
            self.stats.last_error = f"{what}: {self.ph.getTxRxResult(result)}"
            raise CommError(self.stats.last_error)
        code = error & 0x7F
        if code or (error & 0x80 and not hw_ok):
            self.stats.failures += 1
            self.stats.last_error = f"{what}: {self.ph.getRxPacketError(error)}"
            raise CommError(self.stats.last_error)

    def _retry(self, what: str, fn: Callable[[], tuple[int, int]]) -> None:
        for attempt in range(self.retries + 1):
            result, error = self._call(fn)
            try:
                self._check(what, result, error)
                return
            except CommError:
                if attempt == self.retries or (result == COMM_SUCCESS and error & 0x7F):
                    raise
                self.stats.retries += 1

    # -- single-servo access -----------------------------------------------------------------
    def write(self, index: int, register: str, value: int) -> None:
        """Write one register of joint ``index`` (with retries); CommError on failure."""
        j = self.config.joints[index]
        r = REGISTERS[register]
        raw = int(value) & ((1 << (8 * r.size)) - 1)
        fn = {1: self.ph.write1ByteTxRx, 2: self.ph.write2ByteTxRx,
              4: self.ph.write4ByteTxRx}[r.size]
        self._retry(f"{j.name} (ID {j.id}) write {register}={value}",
                    lambda: fn(self.port, j.id, r.address, raw))

    def read(self, index: int, register: str) -> int:
        j = self.config.joints[index]
        r = REGISTERS[register]
        fn = {1: self.ph.read1ByteTxRx, 2: self.ph.read2ByteTxRx,
              4: self.ph.read4ByteTxRx}[r.size]
        out: list[int] = []

        def once() -> tuple[int, int]:
            value, result, error = fn(self.port, j.id, r.address)
            out[:] = [value]
            return result, error
        self._retry(f"{j.name} (ID {j.id}) read {register}", once)
        return _signed(out[0], r.size) if r.signed else out[0]

    def ping(self, index: int) -> int | None:
        """Model number of joint ``index``'s servo, or None if it does not answer."""
        j = self.config.joints[index]
        for _ in range(self.retries + 1):
            model, result, _err = self._call(self.ph.ping, self.port, j.id)
            self.stats.transactions += 1
            if result == COMM_SUCCESS:
                return int(model)
            self.stats.failures += 1
        return None

    # -- start-up ----------------------------------------------------------------------------
    def check_servos(self) -> None:
        """Ping every configured servo; StartupError listing missing/wrong-model joints."""
        missing: list[str] = []
        wrong: dict[str, tuple[str, str]] = {}
        for i, j in enumerate(self.config.joints):
            number = self.ping(i)
            if number is None:
                missing.append(j.name)
            elif number != j.model.number:
                found = model_by_number(number)
                wrong[j.name] = (j.model.name, found.name if found else f"model number {number}")
        if missing or wrong:
            parts = []
            if missing:
                parts.append("missing: " + ", ".join(
                    f"{n} (ID {self.config.joints[self.config.index(n)].id})" for n in missing))
            if wrong:
                parts.append("wrong model: " + ", ".join(
                    f"{n} (ID {self.config.joints[self.config.index(n)].id}) expected {e}, "
                    f"found {f}" for n, (e, f) in wrong.items()))
            raise StartupError(f"Dynamixel start-up check on {self.port_name} failed: "
                               + "; ".join(parts), missing, wrong)

    def configure(self, index: int) -> None:
        """Torque off, then Return Delay Time 0, Drive Mode 0 and Homing Offset 0, operating
        mode, position limits, profile acceleration and velocity and the indirect address blocks of joint
        ``index``.

        Drive Mode 0 (normal direction, velocity-based profile) and Homing Offset 0 make the
        configured ``direction``/``zero_offset`` the only transform between joint angle and
        ticks: a value left in the servo by another tool would otherwise shift or mirror the
        arm, and the tick limits would no longer be the joint limits.
        """
        j = self.config.joints[index]
        self.write(index, "torque_enable", 0)
        self.torque[index] = False
        self.write(index, "return_delay_time", 0)
        self.write(index, "drive_mode", 0)
        self.write(index, "homing_offset", 0)
        # Bus Watchdog (98) exists from firmware v38 on (e-Manual); 0 clears a trip left by a
        # port loss
        self.has_watchdog[index] = self.read(index, "firmware_version") >= BUS_WATCHDOG_FIRMWARE
        if self.has_watchdog[index]:
            self.write(index, "bus_watchdog", 0)
        elif self.bus_watchdog:
            _log.warning("%s (ID %d): firmware older than v%d has no Bus Watchdog: a lost port "
                         "will not stop it in current mode", j.name, j.id,
                         BUS_WATCHDOG_FIRMWARE)
        self.write(index, "operating_mode", OperatingMode.CURRENT_BASED_POSITION)
        self.modes[index] = OperatingMode.CURRENT_BASED_POSITION
        lo, hi = j.tick_limits
        self.write(index, "min_position_limit", lo)
        self.write(index, "max_position_limit", hi)
        # Profile Acceleration before Profile Velocity: a velocity-based trapezoid with the
        # description's acceleration, the profile the mock and host compensation assume
        # (0, the factory value, is a rectangular profile: a velocity step)
        if j.acceleration is not None:
            self.write(index, "profile_acceleration", acceleration_to_raw(j.acceleration))
        self.write(index, "profile_velocity", velocity_to_raw(j.velocity))
        addrs = _READ_ADDRS + _WRITE_ADDRS
        if not self.has_watchdog[index]:   # no register 98: that byte reads register 70
            addrs[_READ_OFF["bus_watchdog"]] = REGISTERS["hardware_error_status"].address
        data = b"".join(a.to_bytes(2, "little") for a in addrs)
        self._retry(f"{j.name} (ID {j.id}) indirect addresses",
                    lambda: self.ph.writeTxRx(self.port, j.id, INDIRECT_ADDRESS_1, len(data),
                                              list(data)))

    def startup(self) -> None:
        """Check all servos, configure them (torque off) and pick fast or plain sync read."""
        self.check_servos()
        for i in range(len(self.config.joints)):
            self.configure(i)
        self.fast = False
        self.fast_error = ""
        if self._fast_refused:
            self.fast_error = self._fast_refused
        elif not self.want_fast:
            self.fast_error = "Fast Sync Read disabled (fast_sync_read false)"
        elif not hasattr(self._reader, "fastSyncRead"):
            self.fast_error = "this dynamixel-sdk has no Fast Sync Read"
        else:
            self.fast = True
            try:
                self.read_state()
            except CommError as exc:
                # MX(2.0) firmware does not implement Fast Sync Read (0x8A): no reply
                self.fast = False
                self.fast_error = f"Fast Sync Read (0x8A) failed at start-up ({exc})"
                self._fast_refused = self.fast_error
        self.read_state()

    # -- cycle -------------------------------------------------------------------------------
    def read_state(self) -> BusState:
        """One sync read of all servos (with retries) -> BusState in SI units."""
        reader = self._reader
        if reader is None:
            raise PortLostError(f"Dynamixel port {self.port_name} is not open")
        fn = (lambda: reader.fastSyncRead()) if self.fast else (lambda: reader.txRxPacket())
        for attempt in range(self.retries + 1):
            result = self._call(fn)
            try:
                self._check("sync read" if not self.fast else "fast sync read", result)
                break
            except CommError:
                if attempt == self.retries:
                    raise
                self.stats.retries += 1
        raw = np.empty((len(self.config.joints), READ_LEN), dtype=np.uint8)
        for i, j in enumerate(self.config.joints):
            raw[i] = reader.data_dict[j.id]
        state = self._decode(raw)
        self.torque = [bool(t) for t in state.torque]
        return state

    def _decode(self, raw: np.ndarray) -> BusState:
        def field_(name: str, dtype: str) -> np.ndarray:
            o = _READ_OFF[name]
            size = REGISTERS[name].size
            return raw[:, o:o + size].copy().view(dtype).reshape(-1).astype(np.int64)

        ticks = field_("present_position", "<i4")
        vel = field_("present_velocity", "<i4")
        cur = field_("present_current", "<i2")
        position = self._dir * ((ticks - CENTER_TICK) * RAD_PER_TICK - self._off)
        current = cur * self._cur * self._dir
        return BusState(
            stamp=time.monotonic(), position=position,
            velocity=self._dir * vel * RADPS_PER_VELOCITY_UNIT,
            effort=current * self._kt, current=current,
            hardware_error=raw[:, _READ_OFF["hardware_error_status"]].astype(np.int64),
            voltage=field_("present_input_voltage", "<u2") * 0.1,
            temperature=raw[:, _READ_OFF["present_temperature"]].astype(float),
            ticks=ticks, bus_watchdog=field_("bus_watchdog", "i1"),
            torque=raw[:, _READ_OFF["torque_enable"]] == 1)

    def goal_ticks(self, position: np.ndarray) -> np.ndarray:
        """Joint angles (rad, finite) -> goal ticks, clamped into each servo's tick limits."""
        t = np.rint(CENTER_TICK + (self._dir * position + self._off) / RAD_PER_TICK)
        return np.clip(t.astype(np.int64), self._lo_tick, self._hi_tick)

    def goal_current(self, effort: np.ndarray) -> np.ndarray:
        """Joint torques (N·m) -> signed raw goal currents, clamped to the current limits."""
        raw = np.rint(self._dir * effort / self._kt / self._cur).astype(np.int64)
        return np.clip(raw, -self._climit, self._climit)

    def write_goals(self, ticks: np.ndarray, current_raw: np.ndarray) -> None:
        """One sync write of goal current (raw) and goal position (ticks) for all servos.

        Ticks are clamped again into the tick limits here, the last step before the wire.
        """
        ticks = np.clip(np.asarray(ticks, dtype=np.int64), self._lo_tick, self._hi_tick)
        current_raw = np.clip(np.asarray(current_raw, dtype=np.int64), -self._climit,
                              self._climit)
        w = self._writer
        if w is None:
            raise PortLostError(f"Dynamixel port {self.port_name} is not open")
        for i, j in enumerate(self.config.joints):
            data = (int(current_raw[i]).to_bytes(2, "little", signed=True)
                    + int(ticks[i]).to_bytes(4, "little", signed=True))
            w.changeParam(j.id, list(data))
        result = self._call(lambda: w.txPacket())
        self._check("sync write", result)

    # -- torque, modes, reboot ---------------------------------------------------------------
    def set_torque(self, indices: Sequence[int], on: bool) -> None:
        for i in indices:
            self.pending_on[i] = False
            self.write(i, "torque_enable", 1 if on else 0)
            self.torque[i] = on

    def restore_torque(self, hardware_error: Sequence[int]) -> list[int]:
        """Turn torque back on where a mode switch turned it off and then failed (a
        transaction lost midway); not on a servo in hardware error (that stays latched).
        Returns the indices restored."""
        done = []
        for i, pending in enumerate(self.pending_on):
            if not pending:
                continue
            if hardware_error[i]:
                self.pending_on[i] = False
                continue
            self.write(i, "torque_enable", 1)
            self.torque[i], self.pending_on[i] = True, False
            done.append(i)
        return done

    def set_mode(self, index: int, mode: int, goal_tick: int, goal_current: int) -> None:
        """Switch joint ``index`` to ``mode`` (torque off -> Bus Watchdog off -> mode ->
        goals -> Bus Watchdog armed in current mode -> torque back). If a transaction fails
        midway, ``pending_on`` remembers that the torque must come back (restore_torque)."""
        was_on = self.torque[index] or self.pending_on[index]
        if self.torque[index]:
            self.pending_on[index] = True
            self.write(index, "torque_enable", 0)
            self.torque[index] = False
        if self.has_watchdog[index]:
            self.write(index, "bus_watchdog", 0)   # also clears a trip (goals writable again)
        self.write(index, "operating_mode", mode)
        self.modes[index] = mode
        lo, hi = self.config.joints[index].tick_limits
        self.write(index, "goal_position", int(min(max(goal_tick, lo), hi)))
        limit = self.config.joints[index].model.current_limit
        self.write(index, "goal_current", int(min(max(goal_current, -limit), limit)))
        if mode == OperatingMode.CURRENT and self.bus_watchdog and self.has_watchdog[index]:
            self.write(index, "bus_watchdog", self.bus_watchdog)
        if was_on:
            self.write(index, "torque_enable", 1)
            self.torque[index], self.pending_on[index] = True, False

    def reboot(self, index: int, timeout: float = 1.0) -> None:
        """REBOOT joint ``index``'s servo, wait until it answers, configure it (torque off)."""
        j = self.config.joints[index]
        self._retry(f"{j.name} (ID {j.id}) reboot",
                    lambda: self.ph.reboot(self.port, j.id))
        self.torque[index] = False
        deadline = time.monotonic() + timeout
        while self.ping(index) is None:
            if time.monotonic() > deadline:
                raise CommError(f"{j.name} (ID {j.id}) did not come back after reboot")
            time.sleep(0.02)
        self.configure(index)

    @staticmethod
    def describe_error(bits: int) -> str:
        return ", ".join(decode_hardware_error(int(bits))) or "none"

    @staticmethod
    def mode_name(mode: int) -> str:
        return OperatingMode.NAMES.get(mode, str(mode))
