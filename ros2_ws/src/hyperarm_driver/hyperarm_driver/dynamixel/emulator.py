"""dxl_emulator: a bus of Dynamixel Protocol 2.0 servos behind a pseudo-terminal (no ROS).

Byte-exact Protocol 2.0 (header, stuffing, CRC-16) with PING, READ, WRITE, SYNC_READ,
FAST_SYNC_READ, SYNC_WRITE, BULK_READ, BULK_WRITE and REBOOT; per-model control tables with
the real addresses (indirect addressing included); first-order motion toward the goal with
the velocity limit; current in the current-based modes (an optional obstacle makes a servo
stall, e.g. the gripper closing on an object). Faults: dropped replies, corrupt CRC,
hardware error bits, slow replies, and the whole port disappearing and coming back.

Run ``dxl_emulator --help``. It prints the pty path to open; ``--link PATH`` keeps a stable
symlink to it (re-created when the port comes back). ``--control PATH`` opens a Unix socket
taking one JSON object per line (``{"op": "fault", "id": 3, "bits": 32}``; see
:meth:`EmulatedBus.control`), answered by one JSON line.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import select
import signal
import socket
import sys
import termios
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import protocol2 as p2
from .control_table import (
    ACCELERATION_UNIT_RPM2, BAUD_RATES, CENTER_TICK, EEPROM_END, INDIRECT_ADDRESS_1, INDIRECT_ADDRESS_29,
    INDIRECT_COUNT, INDIRECT_DATA_1, INDIRECT_DATA_29, MODELS, REGISTERS, TABLE_SIZE,
    TICKS_PER_REV, VELOCITY_UNIT_RPM, Item, ModelSpec, OperatingMode, Register, control_items,
    model_by_name)

__all__ = ["EmulatedServo", "EmulatedBus", "PtyEmulator", "main"]

TICKS_PER_S_PER_VEL_UNIT = VELOCITY_UNIT_RPM / 60.0 * TICKS_PER_REV
# Profile Acceleration (108): 214.577 rev/min² per unit, in ticks/s²
TICKS_PER_S2_PER_ACC_UNIT = ACCELERATION_UNIT_RPM2 / 3600.0 * TICKS_PER_REV
POSITION_TAU = 0.03          # s, first-order time constant of the position loop
POSITION_GAIN = 4.0          # raw current per tick of position error (position loop)
CURRENT_TO_VEL = 2.0         # ticks/s per raw current unit in current mode (free load)
REBOOT_TIME = 0.05           # s a rebooted servo stays silent
TICK = 0.005                 # s, the emulator advances its servos at least this often
STARVED = 0.03               # s: a longer gap between two loop turns means the emulator
                             # process was not scheduled (a real servo never stalls)
_GOAL_REGS = ("goal_position", "goal_current")
_TERMIOS_BAUDS = {getattr(termios, f"B{b}"): b for b in BAUD_RATES.values()
                  if hasattr(termios, f"B{b}")}
_CLEAR_MULTI_TURN = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])   # Clear (0x10): multi-turn reset
# Control Table Backup (0x20), e-Manual Protocol 2.0: P1 0x01 store / 0x02 restore, P2-P5
# "CTRL"; X430/540 from firmware v45; torque on -> Result Fail. Backed up: all of EEPROM,
# the gains, Profile Acceleration/Velocity and the Indirect Addresses; restore puts EEPROM
# back and reboots; the RAM part comes back at start-up with Startup Configuration bit 1.
_BACKUP_KEY = b"CTRL"
BACKUP_FIRMWARE = 45
_BACKUP_RAM = ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain",
               "position_p_gain", "feedforward_2nd_gain", "feedforward_1st_gain",
               "profile_acceleration", "profile_velocity")
STARTUP_RAM_RESTORE = 0x02    # Startup Configuration (60) bit 1
_READS = frozenset((p2.INST_READ, p2.INST_SYNC_READ, p2.INST_FAST_SYNC_READ, p2.INST_BULK_READ,
                    p2.INST_FAST_BULK_READ))
_COMMON = frozenset((p2.INST_PING, p2.INST_READ, p2.INST_WRITE, p2.INST_REG_WRITE,
                     p2.INST_ACTION, p2.INST_FACTORY_RESET, p2.INST_REBOOT, p2.INST_CLEAR,
                     p2.INST_SYNC_READ, p2.INST_SYNC_WRITE, p2.INST_BULK_READ,
                     p2.INST_BULK_WRITE))
# instruction set per series (e-Manual "Instruction" tables: X series firmware v45+ adds Fast
# Sync Read, Fast Bulk Read and Control Table Backup; MX(2.0) has none of them)
_INSTRUCTIONS = {"X": _COMMON | {p2.INST_FAST_SYNC_READ, p2.INST_FAST_BULK_READ,
                                 p2.INST_CONTROL_TABLE_BACKUP},
                 "MX": _COMMON}


def _reg_bytes(name: str, value: int) -> bytes:
    r = REGISTERS[name]
    return int(value).to_bytes(r.size, "little", signed=r.signed)


@dataclass
class WriteRecord:
    """One write the emulator received into a goal register, Torque Enable or Operating
    Mode (after indirect resolution): the instruction that carried it and when (monotonic
    s)."""

    id: int
    register: str
    value: int
    accepted: bool
    mode: int
    inst: int = 0
    t: float = 0.0


class EmulatedServo:
    """One servo: control table bytes + a simple motion model (ticks, s).

    ``baud_index`` is its Baud Rate register (3 = 1 Mbit/s, as the arm is set up; a servo
    from the factory has ID 1 and 1 = 57600, see :meth:`factory`)."""

    def __init__(self, dxl_id: int, model: ModelSpec, position: int = CENTER_TICK, *,
                 baud_index: int = 3) -> None:
        if not 0 <= dxl_id <= p2.MAX_ID:
            raise ValueError(f"servo ID must be 0..{p2.MAX_ID}, got {dxl_id}")
        if baud_index not in BAUD_RATES:
            raise ValueError(f"baud rate index must be one of {sorted(BAUD_RATES)}")
        self.id = dxl_id
        self.model = model
        self.items = control_items(model)
        self._byte_item: list[Item | None] = [None] * TABLE_SIZE
        for it in self.items:
            for a in range(it.address, it.address + it.size):
                self._byte_item[a] = it
        self.table = bytearray(TABLE_SIZE)
        self.pos = float(position)
        self.vel = 0.0          # ticks/s
        self.current = 0.0      # raw current units
        self.obstacle: float | None = None   # tick a moving servo cannot pass
        self.obstacle_side = 1.0
        self.silent_until = 0.0
        self.last_rx = time.monotonic()   # last instruction packet seen (Bus Watchdog)
        self.temperature = 36
        self.voltage = 120      # 0.1 V
        self.overshoot = -float("inf")   # largest excursion past Min/Max Position Limit, ticks
        self.registered: tuple[int, bytes] | None = None   # REG_WRITE waiting for ACTION
        # Control Table Backup area (non-volatile): (EEPROM bytes, RAM address -> bytes)
        self.backup: tuple[bytes, dict[int, bytes]] | None = None
        self._set_eeprom_defaults(dxl_id, baud_index)
        self._set_ram_defaults()

    @classmethod
    def factory(cls, model: ModelSpec) -> "EmulatedServo":
        """A servo as it comes from the factory: ID 1, 57600 baud (e-Manual, Baud Rate 8)."""
        return cls(1, model, baud_index=1)

    @property
    def baud(self) -> int:
        """The servo's bit rate (bit/s) from its Baud Rate register."""
        return BAUD_RATES[self.get("baud_rate")]

    # -- control table ---------------------------------------------------------------------
    def _set(self, name: str, value: int) -> None:
        r = REGISTERS[name] if name in REGISTERS else self._item(name)
        self.table[r.address:r.address + r.size] = int(value).to_bytes(
            r.size, "little", signed=r.signed)

    def _item(self, name: str) -> Item:
        for it in self.items:
            if it.name == name:
                return it
        raise KeyError(name)

    def get(self, name: str) -> int:
        r = REGISTERS[name] if name in REGISTERS else self._item(name)
        return int.from_bytes(self.table[r.address:r.address + r.size], "little",
                              signed=r.signed)

    def _set_eeprom_defaults(self, dxl_id: int, baud_index: int) -> None:
        m = self.model
        self.table[:EEPROM_END] = bytes(EEPROM_END)
        for name, value in (("model_number", m.number), ("firmware_version", 46),
                            ("id", dxl_id), ("baud_rate", baud_index),
                            ("return_delay_time", 250),
                            ("operating_mode", OperatingMode.POSITION),
                            ("secondary_id", 255), ("protocol_type", 2),
                            ("moving_threshold", 10),
                            ("temperature_limit", 80), ("max_voltage_limit", 160),
                            ("min_voltage_limit", 95), ("pwm_limit", 885),
                            ("current_limit", m.current_limit),
                            ("velocity_limit", m.velocity_limit),
                            ("max_position_limit", TICKS_PER_REV - 1),
                            ("min_position_limit", 0), ("shutdown", 0b110100)):
            self._set(name, value)

    def _set_ram_defaults(self) -> None:
        self.table[EEPROM_END:] = bytes(TABLE_SIZE - EEPROM_END)
        self._set("status_return_level", 2)
        self._set("goal_current", self.model.current_limit)
        self._set("goal_pwm", 885)
        self._set("goal_position", int(round(self.pos)))
        for name, value in (("velocity_i_gain", 1920), ("velocity_p_gain", 100),
                            ("position_p_gain", 800)):
            self._set(name, value)
        for n in range(2 * INDIRECT_COUNT):    # Indirect Address n -> Indirect Data n
            a, d = self._indirect(n)
            self.table[a:a + 2] = d.to_bytes(2, "little")
        self.registered = None
        self._refresh_present()

    @staticmethod
    def _indirect(n: int) -> tuple[int, int]:
        """(address of Indirect Address n+1, address of Indirect Data n+1), n = 0..55."""
        if n < INDIRECT_COUNT:
            return INDIRECT_ADDRESS_1 + 2 * n, INDIRECT_DATA_1 + n
        return INDIRECT_ADDRESS_29 + 2 * (n - INDIRECT_COUNT), INDIRECT_DATA_29 + n - INDIRECT_COUNT

    def reboot(self, now: float) -> None:
        """Reset the RAM area (torque off, error cleared); EEPROM kept. With Startup
        Configuration bit 1 (RAM Restore, X series) the backed-up RAM items come back."""
        self._set_ram_defaults()
        if self.backup is not None and self.model.series == "X" \
                and self.get("startup_configuration") & STARTUP_RAM_RESTORE:
            for addr, data in self.backup[1].items():
                self.table[addr:addr + len(data)] = data
        self.vel = 0.0
        self.current = 0.0
        self.silent_until = now + REBOOT_TIME

    def factory_reset(self, option: int, now: float) -> None:
        """FACTORY RESET (0x06): 0xFF everything, 0x01 all but ID, 0x02 all but ID and baud
        rate; ID 1 and 57600 baud are the factory values. The servo restarts."""
        dxl_id = self.id if option in (0x01, 0x02) else 1
        baud = self.get("baud_rate") if option == 0x02 else 1
        self._set_eeprom_defaults(dxl_id, baud)
        self.reboot(now)

    def control_table_backup(self, params: bytes, now: float) -> int:
        """Control Table Backup (0x20): ``params`` = P1 (0x01 store, 0x02 restore) + "CTRL".
        Returns the status error code (the caller sends it; a restore then reboots)."""
        if len(params) != 5:
            return p2.ERR_DATA_LENGTH
        if params[0] not in (0x01, 0x02) or bytes(params[1:]) != _BACKUP_KEY:
            return p2.ERR_DATA_RANGE
        if self.get("torque_enable"):
            return p2.ERR_RESULT_FAIL
        if params[0] == 0x01:
            ram = {}
            for name in _BACKUP_RAM:
                r = self._item(name)
                ram[r.address] = bytes(self.table[r.address:r.address + r.size])
            for n in range(2 * INDIRECT_COUNT):
                a, _ = self._indirect(n)
                ram[a] = bytes(self.table[a:a + 2])
            self.backup = (bytes(self.table[:EEPROM_END]), ram)
            return 0
        if self.backup is None:
            return p2.ERR_RESULT_FAIL
        self.table[:EEPROM_END] = self.backup[0]
        return 0

    def _resolve(self, addr: int) -> int:
        if INDIRECT_DATA_1 <= addr < INDIRECT_DATA_1 + INDIRECT_COUNT:
            a = INDIRECT_ADDRESS_1 + 2 * (addr - INDIRECT_DATA_1)
        elif INDIRECT_DATA_29 <= addr < INDIRECT_DATA_29 + INDIRECT_COUNT:
            a = INDIRECT_ADDRESS_29 + 2 * (addr - INDIRECT_DATA_29)
        else:
            return addr
        return int.from_bytes(self.table[a:a + 2], "little")

    def _refresh_present(self) -> None:
        self._set("present_position", int(round(self.pos)))
        self._set("present_velocity", int(round(self.vel / TICKS_PER_S_PER_VEL_UNIT)))
        self._set("present_current", int(round(self.current)))
        self._set("present_input_voltage", self.voltage)
        self._set("present_temperature", self.temperature)
        self._set("moving", 1 if abs(self.vel) > 1.0 else 0)
        self._set("registered_instruction", 1 if self.registered else 0)
        if self.model.series == "X":
            self._set("backup_ready", 1 if self.backup is not None else 0)
        self._set("realtime_tick", int(time.monotonic() * 1000) % 32768)

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        """(error, data) of a READ of ``length`` bytes at ``addr``: an Access Error if it
        starts on an undefined address or runs past the table (undefined bytes inside a
        longer read read 0, as Dynamixel Wizard's block reads rely on)."""
        if (addr < 0 or length <= 0 or addr + length > TABLE_SIZE
                or self._byte_item[addr] is None):
            return self.status_error(p2.ERR_ACCESS), b""
        self._refresh_present()
        out = bytearray()
        for a in range(addr, addr + length):
            r = self._resolve(a)
            out.append(self.table[r] if 0 <= r < TABLE_SIZE else 0)
        return self.status_error(), bytes(out)

    def status_error(self, code: int = 0) -> int:
        return code | (p2.ERRBIT_ALERT if self.get("hardware_error_status") else 0)

    def _check_write(self, addr: int, n: int) -> tuple[int, list[int]]:
        """(error code, target addresses) of writing ``n`` bytes at ``addr`` (Protocol 2.0
        status errors: Access Error for undefined / read-only addresses, Data Length Error
        for a write that covers an item only in part)."""
        if addr < 0 or n <= 0 or addr + n > TABLE_SIZE:
            return p2.ERR_ACCESS, []
        items = [self._byte_item[a] for a in range(addr, addr + n)]
        if any(it is None or it.access != "RW" for it in items):
            return p2.ERR_ACCESS, []
        first, last = items[0], items[-1]
        assert first is not None and last is not None
        if addr != first.address or addr + n != last.address + last.size:
            return p2.ERR_DATA_LENGTH, []
        targets = [self._resolve(a) for a in range(addr, addr + n)]
        for t, a in zip(targets, range(addr, addr + n)):
            if t == a:
                continue
            it = self._byte_item[t] if 0 <= t < TABLE_SIZE else None
            if it is None or it.access != "RW" or it.name.startswith("indirect_data"):
                return p2.ERR_ACCESS, []
        return 0, targets

    def write(self, addr: int, data: bytes, log: list[WriteRecord] | None = None) -> int:
        """Apply a WRITE; returns the status error byte. Rules of the real firmware
        (e-Manual, Protocol 2.0 status packet errors and the control table): undefined or
        read-only address -> Access Error, part of an item -> Data Length Error, EEPROM with
        torque on -> Access Error, a value outside the item's range -> Data Range Error
        (nothing applied); goal position outside Min/Max Position Limit (position modes) or
        goal current beyond Current Limit -> Data Limit Error (that goal not applied);
        torque on refused during a hardware error (Result Fail)."""
        code, targets = self._check_write(addr, len(data))
        if code:
            return self.status_error(code)
        torque_on = self.get("torque_enable") == 1
        if torque_on and any(t < EEPROM_END for t in targets):
            return self.status_error(p2.ERR_ACCESS)
        new = bytearray(self.table)
        for t, b in zip(targets, data):
            new[t] = b
        touched = set(targets)

        def val(it: Item | Register, table: bytearray) -> int:
            return int.from_bytes(table[it.address:it.address + it.size], "little",
                                  signed=it.signed)

        touched_items = {self._byte_item[t] for t in touched}
        for it in touched_items:
            assert it is not None
            if it.name in _GOAL_REGS:
                continue
            v = val(it, new)
            if it.name == "operating_mode":
                ok = v in self.model.modes
            else:
                ok = it.lo <= v <= it.hi
            if not ok:
                return self.status_error(p2.ERR_DATA_RANGE)

        def touches(name: str) -> bool:
            r = REGISTERS[name]
            return any(a in touched for a in range(r.address, r.address + r.size))

        code = 0
        mode = val(REGISTERS["operating_mode"], new)
        watchdog_tripped = self.get("bus_watchdog") == -1 and not (
            touches("bus_watchdog") and val(REGISTERS["bus_watchdog"], new) == 0)
        for name in _GOAL_REGS:
            if not touches(name):
                continue
            r = REGISTERS[name]
            v = val(r, new)
            if watchdog_tripped:      # goal registers are read-only after a watchdog trip
                if log is not None:
                    log.append(WriteRecord(self.id, name, v, False, mode))
                new[r.address:r.address + r.size] = self.table[r.address:r.address + r.size]
                code = p2.ERR_DATA_RANGE     # (e-Manual: Data Range Error in the status)
                continue
            if name == "goal_position":
                ok = (mode not in (OperatingMode.POSITION, OperatingMode.CURRENT_BASED_POSITION)
                      or val(REGISTERS["min_position_limit"], new) <= v
                      <= val(REGISTERS["max_position_limit"], new))
            else:
                ok = abs(v) <= val(REGISTERS["current_limit"], new)
            if log is not None:
                log.append(WriteRecord(self.id, name, v, ok, mode))
            if not ok:
                new[r.address:r.address + r.size] = self.table[r.address:r.address + r.size]
                code = p2.ERR_DATA_LIMIT
        if touches("torque_enable") and val(REGISTERS["torque_enable"], new) == 1 \
                and self.get("hardware_error_status"):
            new[REGISTERS["torque_enable"].address] = 0
            code = p2.ERR_RESULT_FAIL
        if log is not None:
            for name in ("torque_enable", "operating_mode"):
                if touches(name):
                    log.append(WriteRecord(self.id, name, val(REGISTERS[name], new), True, mode))
        self.table[:] = new
        return self.status_error(code)

    def raise_error(self, bits: int) -> None:
        """Set Hardware Error Status bits; shutdown bits turn the torque off."""
        value = self.get("hardware_error_status") | (bits & 0xFF)
        self._set("hardware_error_status", value)
        if value & self.get("shutdown"):
            self._set("torque_enable", 0)
        if bits & 0x01:
            self.voltage = 70
        if bits & 0x04:
            self.temperature = 85

    def check_bus_watchdog(self, now: float) -> None:
        """Bus Watchdog (98): with torque on and the watchdog armed, no instruction packet
        for longer than its time stops the servo (current mode: goal current 0; position
        modes: hold the present position), sets it to -1 and makes the goal registers
        read-only until 0 is written to it."""
        bw = self.get("bus_watchdog")
        if bw <= 0 or self.get("torque_enable") != 1 or now - self.last_rx <= bw * 0.02:
            return
        self._set("bus_watchdog", -1)
        if self.get("operating_mode") == OperatingMode.CURRENT:
            self._set("goal_current", 0)
        else:
            self._set("goal_position", int(round(self.pos)))

    # -- motion ----------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance the motion model by ``dt`` seconds."""
        if self.get("torque_enable") != 1:
            self.vel = 0.0
            self.current = 0.0
            return
        mode = self.get("operating_mode")
        vmax = self.get("profile_velocity") or self.get("velocity_limit")
        vmax = vmax * TICKS_PER_S_PER_VEL_UNIT
        if mode == OperatingMode.CURRENT:
            goal_i = float(self.get("goal_current"))
            target_v = max(-vmax, min(vmax, goal_i * CURRENT_TO_VEL))
            self.vel += (target_v - self.vel) * min(1.0, dt / POSITION_TAU)
            self.current = goal_i
        elif mode in (OperatingMode.POSITION, OperatingMode.CURRENT_BASED_POSITION,
                      OperatingMode.EXTENDED_POSITION):
            err = self.get("goal_position") - self.pos
            want = max(-vmax, min(vmax, err / POSITION_TAU))
            acc = self.get("profile_acceleration") * TICKS_PER_S2_PER_ACC_UNIT
            if acc > 0:
                # velocity-based trapezoid (Drive Mode 0): accelerate at Profile
                # Acceleration, brake to stop at the goal (v = sqrt(2 a |err|)); 0 = a step
                brake = math.sqrt(2.0 * acc * abs(err))
                want = max(-brake, min(brake, want))
                want = max(self.vel - acc * dt, min(self.vel + acc * dt, want))
            self.vel = want
            limit = (abs(self.get("goal_current")) if mode == OperatingMode.CURRENT_BASED_POSITION
                     else self.get("current_limit"))
            self.current = max(-limit, min(limit, POSITION_GAIN * err))
        else:
            self.vel = 0.0
        new = self.pos + self.vel * dt
        if mode != OperatingMode.CURRENT and abs(self.get("goal_position") - self.pos) <= abs(
                self.vel * dt):
            new = float(self.get("goal_position"))
        if self.obstacle is not None:
            side = self.obstacle_side
            if side * (new - self.obstacle) <= 0.0:   # would reach or cross it: blocked
                new = self.obstacle
                self.vel = 0.0
        self.pos = new
        self.overshoot = max(self.overshoot, new - self.get("max_position_limit"),
                             self.get("min_position_limit") - new)
        if mode != OperatingMode.CURRENT and self.vel == 0.0 and self.obstacle is None \
                and new == self.get("goal_position"):
            self.current = 0.0


@dataclass
class Faults:
    """Fault injection settings of a bus (probabilities 0..1, counts, seconds)."""

    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    reply_delay: float = 0.0
    drop_next: dict[int, int] = field(default_factory=dict)   # id -> replies to drop
    corrupt_next: int = 0


class EmulatedBus:
    """Servos on one bus: turns received bytes into replies (``feed``)."""

    def __init__(self, servos: list[EmulatedServo], seed: int = 0, *,
                 allow_duplicate_ids: bool = False) -> None:
        """``allow_duplicate_ids``: servos may share an ID (e.g. several fresh from the
        factory, all ID 1): they all answer at once, and the host reads a garbled reply."""
        ids = [s.id for s in servos]
        if len(set(ids)) != len(ids) and not allow_duplicate_ids:
            raise ValueError(f"duplicate servo IDs: {ids}")
        self.units = list(servos)
        self.faults = Faults()
        self.reader = p2.PacketReader()
        self.write_log: list[WriteRecord] = []
        self.instructions: dict[int, int] = {}
        self.host_baud: int | None = None     # bit/s the host talks at (None: any)
        self._rng = random.Random(seed)
        self._last = time.monotonic()
        self.frozen = 0.0          # s of emulator starvation skipped (see freeze)
        # lockstep: the servos move ``lockstep`` s per goal SYNC WRITE (one host cycle), on a
        # virtual clock, whatever the wall clock does (deterministic tests of control logic)
        self.lockstep: float | None = None
        self._vt = 0.0

    # -- time ------------------------------------------------------------------------------
    def freeze(self, seconds: float) -> None:
        """The emulator process was not scheduled for ``seconds``: its servos do not move
        over that time (packets that queued up meanwhile are handled as if just in time)."""
        seconds = max(0.0, seconds)
        if self.lockstep is not None:
            return                 # on the virtual clock already
        self._last += seconds
        self.frozen += seconds
        for s in self.servos.values():   # nor does their Bus Watchdog count it
            s.last_rx += seconds

    def _step_virtual(self) -> None:
        """Lockstep: one host cycle of ``lockstep`` s on the virtual clock."""
        assert self.lockstep is not None
        dt, t = self.lockstep, self._vt
        while dt > 1e-12:
            h = min(dt, 0.005)
            t += h
            for s in self.units:
                s.check_bus_watchdog(t)
                s.step(h)
            dt -= h
        self._vt = t

    def set_lockstep(self, dt: float | None) -> None:
        """Lockstep with ``dt`` s per goal SYNC WRITE, or back to the wall clock (None)."""
        if dt is not None and not 0.0 < dt <= 1.0:
            raise ValueError(f"lockstep must be in (0, 1] s, got {dt}")
        self.lockstep = dt
        self._vt = 0.0
        now = time.monotonic()
        self._last = now
        for s in self.units:       # the Bus Watchdog counts on the clock in use
            s.last_rx = 0.0 if dt is not None else now

    def advance(self, now: float | None = None) -> None:
        if self.lockstep is not None:
            return                 # servos move per goal SYNC WRITE (see _step_virtual)
        now = time.monotonic() if now is None else now
        dt = min(max(0.0, now - self._last), 1.0)
        self._last = now
        t = now - dt
        while dt > 0:
            h = min(dt, 0.005)
            t += h
            for s in self.servos.values():
                s.check_bus_watchdog(t)
                s.step(h)
            dt -= h

    @property
    def servos(self) -> dict[int, EmulatedServo]:
        """ID -> servo (of servos sharing an ID, the last one)."""
        return {s.id: s for s in self.units}

    def _hears(self, s: EmulatedServo, now: float) -> bool:
        return s.silent_until <= now and (self.host_baud is None or s.baud == self.host_baud)

    def _addressed(self, dxl_id: int, now: float) -> list[EmulatedServo]:
        """Servos that receive a packet for ``dxl_id`` (all of them for broadcast)."""
        return [s for s in self.units if self._hears(s, now)
                and (dxl_id == p2.BROADCAST_ID or s.id == dxl_id)]

    def _available(self, dxl_id: int, now: float) -> EmulatedServo | None:
        found = self._addressed(dxl_id, now) if dxl_id != p2.BROADCAST_ID else []
        return found[0] if len(found) == 1 else None

    # -- replies ---------------------------------------------------------------------------
    def _emit(self, dxl_id: int, packet: bytes, out: list[bytes]) -> None:
        n = self.faults.drop_next.get(dxl_id, 0)
        if n > 0:
            self.faults.drop_next[dxl_id] = n - 1
            return
        if self.faults.drop_rate and self._rng.random() < self.faults.drop_rate:
            return
        if self.faults.corrupt_next > 0 or (
                self.faults.corrupt_rate and self._rng.random() < self.faults.corrupt_rate):
            self.faults.corrupt_next = max(0, self.faults.corrupt_next - 1)
            packet = packet[:-1] + bytes([packet[-1] ^ 0x5A])
        out.append(packet)

    def feed(self, data: bytes, now: float | None = None,
             arrived_after: float | None = None) -> list[bytes]:
        """Bytes from the host -> reply packets, in order. ``now``: when they were taken;
        ``arrived_after``: the last time the port was seen empty before them (the
        inter-byte gap rule, :class:`~.protocol2.PacketReader`)."""
        now = time.monotonic() if now is None else now
        out: list[bytes] = []
        for pkt in self.reader.feed(data, now, arrived_after):
            self.advance(now)
            for s in self.units:   # every instruction packet feeds Bus Watchdog
                if self._hears(s, now):
                    s.last_rx = now if self.lockstep is None else self._vt
            self.instructions[pkt.instruction] = self.instructions.get(pkt.instruction, 0) + 1
            n0 = len(self.write_log)
            if pkt.crc_ok:
                self._handle(pkt, now, out)
            elif pkt.id != p2.BROADCAST_ID:
                # Protocol 2.0: "CRC Error: CRC of the sent Packet does not match"
                for s in self._addressed(pkt.id, now):
                    self._reply(s, pkt.instruction, p2.build_status(
                        s.id, s.status_error(p2.ERR_CRC)), out)
            for rec in self.write_log[n0:]:
                rec.inst, rec.t = pkt.instruction, now
            if self.lockstep is not None and pkt.instruction == p2.INST_SYNC_WRITE:
                self._step_virtual()
        return out

    def _reply(self, s: EmulatedServo, inst: int, packet: bytes, out: list[bytes]) -> None:
        """Send ``packet`` if the servo's Status Return Level (68) allows it for ``inst``:
        0 = PING only, 1 = PING and reads, 2 = every instruction (e-Manual)."""
        level = s.get("status_return_level")
        if inst == p2.INST_PING or level >= 2 or (level == 1 and inst in _READS):
            self._emit(s.id, packet, out)

    def _unicast(self, pkt: p2.Packet, now: float, out: list[bytes], answer) -> None:
        """Run ``answer(servo) -> status packet or None`` on the servo(s) with the packet's
        ID; two servos with one ID answer at once: the host gets a garbled reply."""
        found = self._addressed(pkt.id, now)
        replies = [(s, answer(s)) for s in found]
        replies = [(s, r) for s, r in replies if r is not None]
        if len(replies) > 1:        # bus collision
            for s, r in replies:
                self._reply(s, pkt.instruction, r[:-2] + bytes([r[-2] ^ 0xA5, r[-1]]), out)
            return
        for s, r in replies:
            self._reply(s, pkt.instruction, r, out)

    def _write_effects(self, s: EmulatedServo) -> None:
        """A new ID or baud rate takes effect once the status packet is sent."""
        s.id = s.get("id")

    def _handle(self, pkt: p2.Packet, now: float, out: list[bytes]) -> None:
        inst, prm = pkt.instruction, pkt.params
        broadcast = pkt.id == p2.BROADCAST_ID
        if inst == p2.INST_PING:
            found = self._addressed(pkt.id, now)
            for s in sorted(found, key=lambda s: s.id):
                data = _reg_bytes("model_number", s.model.number) + bytes(
                    [s.get("firmware_version")])
                reply = p2.build_status(s.id, s.status_error(), data)
                if sum(o.id == s.id for o in found) > 1:     # same ID: they collide
                    reply = reply[:-2] + bytes([reply[-2] ^ 0xA5, reply[-1]])
                self._emit(s.id, reply, out)
            return
        targets = self._addressed(pkt.id, now)
        supported = [s for s in targets if inst in _INSTRUCTIONS[s.model.series]]
        if not broadcast and targets and not supported:
            self._unicast(pkt, now, out, lambda s: p2.build_status(
                s.id, s.status_error(p2.ERR_INSTRUCTION)))
            return
        if inst == p2.INST_READ and not broadcast:
            def answer(s: EmulatedServo) -> bytes:
                if len(prm) != 4:
                    return p2.build_status(s.id, s.status_error(p2.ERR_DATA_LENGTH))
                err, data = s.read(prm[0] | prm[1] << 8, prm[2] | prm[3] << 8)
                return p2.build_status(s.id, err, data)
            self._unicast(pkt, now, out, answer)
        elif inst in (p2.INST_WRITE, p2.INST_REG_WRITE):
            def answer(s: EmulatedServo) -> bytes:
                if len(prm) < 3:
                    return p2.build_status(s.id, s.status_error(p2.ERR_DATA_LENGTH))
                addr = prm[0] | prm[1] << 8
                if inst == p2.INST_REG_WRITE:
                    code, _ = s._check_write(addr, len(prm) - 2)
                    if not code:
                        s.registered = (addr, bytes(prm[2:]))
                    return p2.build_status(s.id, s.status_error(code))
                return p2.build_status(s.id, s.write(addr, prm[2:], self.write_log))
            for s in supported if broadcast else []:
                answer(s)
                self._write_effects(s)
            if not broadcast:
                self._unicast(pkt, now, out, answer)
                for s in targets:
                    self._write_effects(s)
        elif inst == p2.INST_ACTION:
            def answer(s: EmulatedServo) -> bytes:
                if s.registered is None:   # "Action has been used without Reg Write"
                    return p2.build_status(s.id, s.status_error(p2.ERR_INSTRUCTION))
                (addr, data), s.registered = s.registered, None
                return p2.build_status(s.id, s.write(addr, data, self.write_log))
            if broadcast:
                for s in supported:
                    if s.registered is not None:
                        answer(s)
                        self._write_effects(s)
            else:
                self._unicast(pkt, now, out, answer)
                for s in targets:
                    self._write_effects(s)
        elif inst == p2.INST_REBOOT and not broadcast:
            self._unicast(pkt, now, out, lambda s: p2.build_status(s.id, s.status_error()))
            for s in targets:
                s.reboot(now)
        elif inst == p2.INST_FACTORY_RESET:
            option = prm[0] if len(prm) == 1 else None
            if broadcast:
                if option in (0x01, 0x02):     # 0xFF is refused for broadcast (e-Manual)
                    for s in supported:
                        s.factory_reset(option, now)
                        s.id = s.get("id")
                return
            def answer(s: EmulatedServo) -> bytes:
                if option is None:
                    return p2.build_status(s.id, s.status_error(p2.ERR_DATA_LENGTH))
                if option not in (0x01, 0x02, 0xFF):
                    return p2.build_status(s.id, s.status_error(p2.ERR_DATA_RANGE))
                return p2.build_status(s.id, s.status_error())
            self._unicast(pkt, now, out, answer)
            if option in (0x01, 0x02, 0xFF):
                for s in targets:
                    s.factory_reset(option, now)
                    s.id = s.get("id")
        elif inst == p2.INST_CONTROL_TABLE_BACKUP:
            results: dict[int, int] = {}

            def answer(s: EmulatedServo) -> bytes:
                if s.get("firmware_version") < BACKUP_FIRMWARE:
                    return p2.build_status(s.id, s.status_error(p2.ERR_INSTRUCTION))
                results[id(s)] = code = s.control_table_backup(prm, now)
                return p2.build_status(s.id, s.status_error(code))
            if broadcast:
                for s in supported:
                    answer(s)
            else:
                self._unicast(pkt, now, out, answer)
            for s in supported:        # a restore reboots once its status has been sent
                if results.get(id(s)) == 0 and prm[:1] == b"\x02":
                    s.reboot(now)
                    s.id = s.get("id")
        elif inst == p2.INST_CLEAR and not broadcast:
            def answer(s: EmulatedServo) -> bytes:
                if len(prm) != 5:
                    return p2.build_status(s.id, s.status_error(p2.ERR_DATA_LENGTH))
                if bytes(prm) != _CLEAR_MULTI_TURN:
                    return p2.build_status(s.id, s.status_error(p2.ERR_DATA_RANGE))
                if abs(s.vel) > 1.0:     # only while stopped (e-Manual, Clear)
                    return p2.build_status(s.id, s.status_error(p2.ERR_RESULT_FAIL))
                s.pos = s.pos % TICKS_PER_REV
                s._set("goal_position", int(round(s.pos)))
                return p2.build_status(s.id, s.status_error())
            self._unicast(pkt, now, out, answer)
        elif inst in (p2.INST_SYNC_READ, p2.INST_FAST_SYNC_READ) and broadcast and len(prm) >= 5:
            addr, length = prm[0] | prm[1] << 8, prm[2] | prm[3] << 8
            ids = list(prm[4:])
            if inst == p2.INST_SYNC_READ:
                for i in ids:
                    for s in self._addressed(i, now):
                        if inst in _INSTRUCTIONS[s.model.series]:
                            err, data = s.read(addr, length)
                            self._reply(s, inst, p2.build_status(i, err, data), out)
            else:
                self._fast_read([(i, addr, length) for i in ids], inst, now, out)
        elif inst in (p2.INST_BULK_READ, p2.INST_FAST_BULK_READ) and broadcast:
            req = [(prm[k], prm[k + 1] | prm[k + 2] << 8, prm[k + 3] | prm[k + 4] << 8)
                   for k in range(0, len(prm) - 4, 5)]
            if inst == p2.INST_BULK_READ:
                for i, addr, length in req:
                    for s in self._addressed(i, now):
                        err, data = s.read(addr, length)
                        self._reply(s, inst, p2.build_status(i, err, data), out)
            else:
                self._fast_read(req, inst, now, out)
        elif inst == p2.INST_SYNC_WRITE and broadcast and len(prm) >= 4:
            addr, length = prm[0] | prm[1] << 8, prm[2] | prm[3] << 8
            body = prm[4:]
            step = 1 + length
            for k in range(0, len(body) - step + 1, step):
                for s in self._addressed(body[k], now):
                    s.write(addr, body[k + 1:k + step], self.write_log)
                    self._write_effects(s)
        elif inst == p2.INST_BULK_WRITE and broadcast:
            k = 0
            while k + 5 <= len(prm):
                i, addr, length = prm[k], prm[k + 1] | prm[k + 2] << 8, prm[k + 3] | prm[k + 4] << 8
                for s in self._addressed(i, now):
                    s.write(addr, prm[k + 5:k + 5 + length], self.write_log)
                    self._write_effects(s)
                k += 5 + length
        elif not broadcast:
            self._unicast(pkt, now, out, lambda s: p2.build_status(
                s.id, s.status_error(p2.ERR_INSTRUCTION)))

    def _fast_read(self, req: list[tuple[int, int, int]], inst: int, now: float,
                   out: list[bytes]) -> None:
        """Fast Sync Read (0x8A) / Fast Bulk Read (0x9A): one status packet, each servo
        appending its segment after its predecessor's; a servo that does not take part (an
        MX(2.0), which has neither instruction, or a silent one) ends the chain there."""
        items = []
        for i, addr, length in req:
            found = self._addressed(i, now)
            s = found[0] if len(found) == 1 else None
            if s is None or inst not in _INSTRUCTIONS[s.model.series] \
                    or s.get("status_return_level") == 0:
                break
            if self.faults.drop_next.get(i, 0) > 0:   # this servo stays silent
                self.faults.drop_next[i] -= 1
                break
            err, data = s.read(addr, length)
            if not data:          # an error reply carries no data: it would break the chain
                data = bytes(length)
            items.append((i, err, data))
        if not items:
            return
        full = p2.build_fast_sync_status(items)
        if len(items) < len(req):
            # the chain stops at the silent servo: the length field announces all of them
            length_all = 1 + sum(4 + n for _, _, n in req)
            full = full[:5] + bytes([length_all & 0xFF, length_all >> 8]) + full[7:]
        self._emit(-1, full, out)  # per-servo drops handled above

    # -- control ---------------------------------------------------------------------------
    def control(self, cmd: dict[str, Any]) -> dict[str, Any]:
        """Apply a control command (from the control socket or a test); returns a reply.

        ops: ``fault`` {id, bits} raise Hardware Error bits; ``clear`` {id} clear them;
        ``drop`` {id, count} drop that servo's next replies; ``corrupt`` {count} corrupt the
        CRC of the next replies; ``rates`` {drop_rate, corrupt_rate, reply_delay};
        ``obstacle`` {id, position (tick) or null}; ``set`` {id, position (tick)};
        ``register`` {id, name, value} set a register (e.g. an old ``firmware_version``);
        ``state`` -> per-servo registers; ``write_log`` {clear} -> goal writes received;
        ``stats`` -> packet counts.
        """
        op = cmd.get("op")
        try:
            if op == "fault":
                self.servos[int(cmd["id"])].raise_error(int(cmd["bits"]))
            elif op == "clear":
                s = self.servos[int(cmd["id"])]
                s._set("hardware_error_status", 0)
            elif op == "drop":
                self.faults.drop_next[int(cmd["id"])] = int(cmd.get("count", 1))
            elif op == "corrupt":
                self.faults.corrupt_next = int(cmd.get("count", 1))
            elif op == "rates":
                for k in ("drop_rate", "corrupt_rate", "reply_delay"):
                    if k in cmd:
                        setattr(self.faults, k, float(cmd[k]))
            elif op == "obstacle":
                pos = cmd.get("position")
                s = self.servos[int(cmd["id"])]
                s.obstacle = None if pos is None else float(pos)
                if s.obstacle is not None:   # the servo stays on the side it is on now
                    s.obstacle_side = 1.0 if s.pos >= s.obstacle else -1.0
            elif op == "set":
                self.servos[int(cmd["id"])].pos = float(cmd["position"])
            elif op == "register":        # poke any register, as Dynamixel Wizard would
                self.servos[int(cmd["id"])]._set(str(cmd["name"]), int(cmd["value"]))
            elif op == "overshoot":       # largest excursion past the limits, then reset
                s = self.servos[int(cmd["id"])]
                value, s.overshoot = s.overshoot, -float("inf")
                return {"ok": True, "ticks": value if value > -float("inf") else None}
            elif op == "lockstep":        # {"dt": s per goal SYNC WRITE, or null}
                dt = cmd.get("dt")
                self.set_lockstep(None if dt is None else float(dt))
            elif op == "units":           # every servo, also several sharing one ID
                return {"ok": True, "units": [
                    {"id": s.id, "model": s.model.name, "baud": s.baud} for s in self.units]}
            elif op == "state":
                self.advance()
                return {"ok": True, "servos": {str(i): self._state(s)
                                               for i, s in self.servos.items()}}
            elif op == "write_log":
                log = [vars(r) for r in self.write_log]
                if cmd.get("clear"):
                    self.write_log.clear()
                return {"ok": True, "log": log}
            elif op == "stats":
                return {"ok": True, "packets": self.reader.packets, "frozen_s": self.frozen,
                        "crc_errors": self.reader.crc_errors,
                        "frame_timeouts": self.reader.timeouts, "bytes_in": self.reader.bytes,
                        "last_gap_s": self.reader.last_gap,
                        "instructions": {hex(k): v for k, v in self.instructions.items()}}
            elif op != "ping":
                return {"ok": False, "error": f"unknown op {op!r}"}
        except (KeyError, ValueError, TypeError) as exc:
            return {"ok": False, "error": f"{op}: bad or missing argument ({exc})"}
        return {"ok": True}

    @staticmethod
    def _state(s: EmulatedServo) -> dict[str, Any]:
        s._refresh_present()
        names = ("model_number", "firmware_version", "id", "baud_rate", "status_return_level",
                 "registered_instruction", "led", "operating_mode", "torque_enable",
                 "goal_position",
                 "goal_current", "present_position", "present_velocity", "present_current",
                 "hardware_error_status", "return_delay_time", "min_position_limit",
                 "max_position_limit", "profile_acceleration", "profile_velocity", "current_limit",
                 "drive_mode",
                 "homing_offset", "bus_watchdog")
        return {n: s.get(n) for n in names}


class PtyEmulator:
    """Serves an :class:`EmulatedBus` on a pseudo-terminal (optionally a stable symlink)."""

    def __init__(self, bus: EmulatedBus, link: str | None = None,
                 control: str | None = None) -> None:
        self.bus = bus
        self.link = Path(link) if link else None
        self.control_path = Path(control) if control else None
        self.master: int | None = None
        self._keep_slave: int | None = None
        self.device = ""
        self._pending: list[tuple[float, bytes]] = []
        self._back_at: float | None = None
        self._ctl_srv: socket.socket | None = None
        self._clients: dict[int, tuple[socket.socket, bytearray]] = {}
        self._stop = False
        self._last_turn: float | None = None
        self._last_read = 0.0       # when host bytes were last read (monotonic s)

    def open(self) -> str:
        """Create the pty (and the link); returns the device path."""
        master, slave = os.openpty()
        tty.setraw(slave, termios.TCSANOW)
        os.set_blocking(master, False)
        self.master, self._keep_slave = master, slave
        self.device = os.ttyname(slave)
        if self.link:
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.device)
            os.replace(tmp, self.link)
        return self.device

    def close_port(self) -> None:
        """The port disappears: the pty is closed and the link removed."""
        if self.link:
            self.link.unlink(missing_ok=True)
        for fd in (self.master, self._keep_slave):
            if fd is not None:
                os.close(fd)
        self.master = self._keep_slave = None
        self._pending.clear()

    def disappear(self, seconds: float) -> None:
        self.close_port()
        self._back_at = time.monotonic() + max(0.0, seconds)

    def _open_control(self) -> None:
        if not self.control_path:
            return
        self.control_path.unlink(missing_ok=True)
        srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        srv.bind(str(self.control_path))
        srv.listen(4)
        srv.setblocking(False)
        self._ctl_srv = srv

    def _on_control_line(self, line: bytes) -> dict[str, Any]:
        try:
            cmd = json.loads(line)
            if not isinstance(cmd, dict):
                raise ValueError("expected a JSON object")
        except ValueError as exc:
            return {"ok": False, "error": f"bad JSON: {exc}"}
        if cmd.get("op") == "disappear":
            self.disappear(float(cmd.get("seconds", 1.0)))
            return {"ok": True}
        if cmd.get("op") == "device":
            return {"ok": True, "device": self.device if self.master is not None else None}
        return self.bus.control(cmd)

    def stop(self) -> None:
        self._stop = True

    def serve_forever(self) -> None:
        """Run until :meth:`stop` (or SIGINT/SIGTERM in :func:`main`)."""
        if self.master is None:
            self.open()
        self._open_control()
        try:
            while not self._stop:
                self._once()
        finally:
            self.close_port()
            for c, _ in self._clients.values():
                c.close()
            if self._ctl_srv:
                self._ctl_srv.close()
                if self.control_path:
                    self.control_path.unlink(missing_ok=True)

    def _once(self) -> None:
        now = time.monotonic()
        if self.master is None and self._back_at is not None and now >= self._back_at:
            self._back_at = None
            self.open()
            print(f"dxl_emulator: port back on {self.device}", flush=True)
        fds = [c.fileno() for c, _ in self._clients.values()]
        if self._ctl_srv:
            fds.append(self._ctl_srv.fileno())
        if self.master is not None:
            fds.append(self.master)
        if self._last_turn is not None and now - self._last_turn > STARVED:
            self.bus.freeze(now - self._last_turn)    # not scheduled between two turns
        self.bus.advance(now)
        timeout = TICK
        if self._pending:
            timeout = max(0.0, min(timeout, self._pending[0][0] - now))
        if self._back_at is not None:
            timeout = max(0.0, min(timeout, self._back_at - now))
        # when the host's bytes came: after the last moment the port was seen empty (the
        # Protocol 2.0 inter-byte gap is judged on that, see PacketReader)
        empty_at = time.monotonic()
        if self.master is not None and select.select([self.master], [], [], 0)[0]:
            empty_at = self._last_read         # already waiting: came after the last read
        readable, _, _ = select.select(fds, [], [], timeout)
        before, now = now, time.monotonic()
        if now - before > timeout + STARVED:    # runnable, but not scheduled, in select
            self.bus.freeze(now - before - timeout)
        for fd in readable:
            if fd == self.master:
                try:
                    data = os.read(fd, 65536)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    data = b""
                if data:
                    self.bus.host_baud = self._host_baud()
                    delay = self.bus.faults.reply_delay
                    self._last_read = t_read = time.monotonic()   # the bytes came before
                    for reply in self.bus.feed(data, t_read, empty_at):
                        if delay > 0:
                            self._pending.append((now + delay, reply))
                        else:
                            self._write(reply)
            elif self._ctl_srv and fd == self._ctl_srv.fileno():
                conn, _ = self._ctl_srv.accept()
                conn.setblocking(False)
                self._clients[conn.fileno()] = (conn, bytearray())
            elif fd in self._clients:
                conn, buf = self._clients[fd]
                try:
                    chunk = conn.recv(65536)
                except BlockingIOError:
                    continue
                except OSError:            # reset by a client that went away
                    chunk = b""
                if not chunk:
                    conn.close()
                    del self._clients[fd]
                    continue
                buf += chunk
                while b"\n" in buf:
                    line, _, rest = bytes(buf).partition(b"\n")
                    buf[:] = rest
                    reply = json.dumps(self._on_control_line(line)).encode() + b"\n"
                    try:
                        conn.setblocking(True)
                        conn.sendall(reply)
                        conn.setblocking(False)
                    except OSError:        # the client closed before reading its reply
                        conn.close()
                        del self._clients[fd]
                        break
        now = time.monotonic()
        while self._pending and self._pending[0][0] <= now:
            self._write(self._pending.pop(0)[1])
        self._last_turn = time.monotonic()

    def _host_baud(self) -> int | None:
        """The bit rate the host set on its end of the pty (termios), None if not a
        standard rate (then every servo hears it)."""
        if self._keep_slave is None:
            return None
        try:
            speed = termios.tcgetattr(self._keep_slave)[4]
        except termios.error:
            return None
        return _TERMIOS_BAUDS.get(speed)

    def _write(self, data: bytes) -> None:
        if self.master is None:
            return
        try:
            os.write(self.master, data)
        except (BlockingIOError, OSError):
            pass  # nobody reading: the bytes are lost, as on a real bus


class EmulatorControl:
    """Client of an emulator's control socket (for tests and scripts)."""

    def __init__(self, path: str | os.PathLike[str], timeout: float = 5.0) -> None:
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(timeout)
        self._sock.connect(str(path))
        self._buf = b""

    def __call__(self, op: str, **kwargs: Any) -> dict[str, Any]:
        self._sock.sendall(json.dumps({"op": op, **kwargs}).encode() + b"\n")
        while b"\n" not in self._buf:
            chunk = self._sock.recv(1 << 20)
            if not chunk:
                raise ConnectionError("emulator control socket closed")
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        reply = json.loads(line)
        if not reply.get("ok"):
            raise RuntimeError(f"emulator: {reply.get('error')}")
        return reply

    def close(self) -> None:
        self._sock.close()


def servos_from_description(path: str | None, omit: list[int],
                            models: dict[int, str]) -> list[EmulatedServo]:
    """One emulated servo per joint of the description (IDs omitted, models overridden)."""
    from hyperarm_description.model import load_description

    desc = load_description(path or None)
    specs = [(j.servo.id, j.servo.model) for j in desc.joints]
    specs.append((desc.gripper.servo.id, desc.gripper.servo.model))
    out = []
    for sid, model in specs:
        if sid in omit:
            continue
        out.append(EmulatedServo(sid, model_by_name(models.get(sid, model))))
    return out


def _parse_servo(item: str) -> EmulatedServo:
    """``ID:MODEL[@BAUD]`` -> a servo (BAUD in bit/s, one of the Baud Rate register's)."""
    sid, _, rest = item.partition(":")
    model, _, baud = rest.partition("@")
    index = 3
    if baud:
        by_rate = {v: k for k, v in BAUD_RATES.items()}
        if not baud.strip().isdigit() or int(baud) not in by_rate:
            raise ValueError(f"--servos {item!r}: baud must be one of "
                             f"{', '.join(map(str, BAUD_RATES.values()))}")
        index = by_rate[int(baud)]
    if not sid.strip().isdigit():
        raise ValueError(f"--servos expects ID:MODEL[@BAUD], got {item!r}")
    return EmulatedServo(int(sid), model_by_name(model.strip()), baud_index=index)


def _parse_model_overrides(items: list[str]) -> dict[int, str]:
    out = {}
    for item in items:
        sid, sep, model = item.partition("=")
        if not sep or not sid.isdigit():
            raise argparse.ArgumentTypeError(f"--model expects ID=MODEL, got {item!r}")
        model_by_name(model)
        out[int(sid)] = model
    return out


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="dxl_emulator",
        description="Emulate a bus of Dynamixel Protocol 2.0 servos on a pseudo-terminal. "
                    "Prints the device path; open it with the driver (port:=PATH).")
    ap.add_argument("--description", default="",
                    help="robot description YAML giving the servo IDs/models "
                         "('' = the packaged one)")
    ap.add_argument("--servos", default="",
                    help="instead of the description: comma-separated ID:MODEL[@BAUD] list, "
                         "e.g. 1:XM430-W350,2:MX-64@57600 (default baud 1000000; "
                         f"models: {', '.join(MODELS)})")
    ap.add_argument("--factory", action="append", default=[], metavar="MODEL",
                    help="add a servo as it comes from the factory: ID 1, 57600 baud "
                         "(repeatable; several share ID 1 and collide, as on a real bus)")
    ap.add_argument("--omit", type=int, action="append", default=[], metavar="ID",
                    help="leave this servo off the bus (repeatable)")
    ap.add_argument("--model", action="append", default=[], metavar="ID=MODEL",
                    help="emulate servo ID as another model (repeatable)")
    ap.add_argument("--link", default="",
                    help="stable symlink to the pty, re-created when the port comes back")
    ap.add_argument("--control", default="",
                    help="Unix socket for fault injection/inspection (JSON lines)")
    ap.add_argument("--drop-rate", type=float, default=0.0, help="probability a reply is lost")
    ap.add_argument("--corrupt-rate", type=float, default=0.0,
                    help="probability a reply has a bad CRC")
    ap.add_argument("--reply-delay", type=float, default=0.0, help="extra reply delay, s")
    ap.add_argument("--seed", type=int, default=0, help="random seed of the fault injection")
    ap.add_argument("--lockstep", type=float, default=0.0, metavar="S",
                    help="move the servos S seconds per goal Sync Write (one host cycle) "
                         "instead of with the wall clock (0 = off): deterministic tests")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.servos:
            servos = [_parse_servo(item) for item in args.servos.split(",")]
        elif args.factory:
            servos = []
        else:
            servos = servos_from_description(args.description, args.omit,
                                             _parse_model_overrides(args.model))
        servos += [EmulatedServo.factory(model_by_name(m)) for m in args.factory]
        bus = EmulatedBus(servos, seed=args.seed, allow_duplicate_ids=True)
    except (ValueError, argparse.ArgumentTypeError, OSError) as exc:
        print(f"dxl_emulator: {exc}", file=sys.stderr)
        return 2
    bus.faults.drop_rate = args.drop_rate
    bus.faults.corrupt_rate = args.corrupt_rate
    bus.faults.reply_delay = args.reply_delay
    if args.lockstep:
        try:
            bus.set_lockstep(args.lockstep)
        except ValueError as exc:
            print(f"dxl_emulator: {exc}", file=sys.stderr)
            return 2
    emu = PtyEmulator(bus, link=args.link or None, control=args.control or None)
    device = emu.open()
    signal.signal(signal.SIGTERM, lambda *_: emu.stop())
    signal.signal(signal.SIGINT, lambda *_: emu.stop())
    ids = ", ".join(f"{s.id}:{s.model.name}" + (f"@{s.baud}" if s.baud != 1_000_000 else "")
                    for s in servos)
    print(device, flush=True)
    print(f"dxl_emulator: {len(servos)} servos [{ids}] on {device}"
          + (f" (link {args.link})" if args.link else "")
          + (f", control socket {args.control}" if args.control else ""), flush=True)
    emu.serve_forever()
    return 0


if __name__ == "__main__":
    sys.exit(main())
