"""Core tier: Protocol 2.0 codec, model table, config conversions, command validation,
emulated servo rules (all in-process, no rclpy, no pty)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from dynamixel_sdk import Protocol2PacketHandler
from hypothesis import given, settings
from hypothesis import strategies as hs

from hyperarm_description.model import load_description
from hyperarm_driver.dynamixel import protocol2 as p2
from hyperarm_driver.dynamixel.bus import DynamixelBus, ftdi_latency_timer
from hyperarm_driver.dynamixel.config import JointServo, bus_config_from_description
from hyperarm_driver.dynamixel.control_table import (
    MODELS, REGISTERS, decode_hardware_error, model_by_name, model_by_number)
from hyperarm_driver.dynamixel.driver import DynamixelDriver
from hyperarm_driver.dynamixel.emulator import EmulatedBus, EmulatedServo
from hyperarm_driver.dynamixel.errors import CommandError, ConfigError, PortOpenError

pytestmark = pytest.mark.core


def test_crc_matches_the_sdk_and_a_manual_example():
    # e-Manual example: PING ID 1 -> FF FF FD 00 01 03 00 01 19 4E
    assert p2.build_packet(1, p2.INST_PING) == bytes.fromhex("fffffd0001030001194e")
    ref = Protocol2PacketHandler()
    data = bytes(range(256)) * 2
    assert p2.crc16(data) == ref.updateCRC(0, list(data), len(data))


@settings(max_examples=200, deadline=None)
@given(hs.binary(max_size=64))
def test_stuffing_round_trip_and_reader_decodes(params):
    pkt = p2.build_packet(7, p2.INST_WRITE, params)
    body = pkt[7:-2]
    assert p2.unstuff(body) == bytes([p2.INST_WRITE]) + params
    # the SDK's stuffing gives the same bytes
    raw = list(p2.build_packet(7, p2.INST_WRITE, params, stuffing=False))
    assert bytes(Protocol2PacketHandler().addStuffing(raw))[:-2] == pkt[:-2]
    out = p2.PacketReader().feed(b"\x00\xff" + pkt)
    assert out == [p2.Packet(7, p2.INST_WRITE, params)]


def test_reader_flags_bad_crc_and_resynchronises():
    good = p2.build_packet(3, p2.INST_READ, bytes([132, 0, 4, 0]))
    bad = good[:-1] + bytes([good[-1] ^ 1])
    r = p2.PacketReader()
    got = r.feed(bad[:5]) + r.feed(bad[5:] + b"\x12" + good)
    assert [(pk.id, pk.crc_ok) for pk in got] == [(3, False), (3, True)]
    assert r.crc_errors == 1 and r.packets == 1


def test_reader_drops_an_incomplete_packet_after_a_byte_gap():
    """issue 16: a corrupt length field (4080) must not deafen the bus until 4 KB came in
    and then replay what was buffered; issue 24 item 9: a servo drops a packet whose bytes
    come more than 1.5 ms apart (e-Manual, Protocol 2.0), so the next bytes are read afresh."""
    ping = p2.build_packet(1, p2.INST_PING)
    corrupt = bytearray(p2.build_packet(1, p2.INST_WRITE, bytes([65, 0, 1])))
    corrupt[5:7] = (4080).to_bytes(2, "little")
    r = p2.PacketReader()
    assert r.feed(bytes(corrupt), now=0.0) == []
    assert r.feed(ping, now=0.001) == []         # within the gap: part of that packet
    assert r.feed(ping, now=0.001 + p2.BYTE_GAP_TIMEOUT + 0.0001) == [
        p2.Packet(1, p2.INST_PING, b"")]
    assert r.timeouts == 1
    # the example: a ping split 7 + 3 bytes, 20 ms apart, is not answered
    r = p2.PacketReader()
    assert r.feed(ping[:7], now=0.0) == [] and r.feed(ping[7:], now=0.02) == []
    assert r.timeouts == 1 and r.last_gap == pytest.approx(0.02)
    assert r.feed(ping, now=0.021) == [p2.Packet(1, p2.INST_PING, b"")]
    # the gap runs from when the earlier bytes were taken to the earliest the later ones can
    # have come (arrived_after): a reader that was not scheduled does not drop a packet
    r = p2.PacketReader()
    r.feed(ping[:7], now=0.0)
    assert r.feed(ping[7:], now=0.05, arrived_after=0.001) == [p2.Packet(1, p2.INST_PING, b"")]
    r.feed(ping[:7], now=0.1)
    assert r.feed(ping[7:], now=0.2, arrived_after=0.102) == [] and r.timeouts == 1


@pytest.mark.parametrize("seed", range(5))
def test_reader_byte_gap_rule_on_random_splits(seed: int):
    """Random packets (stuffed, up to 300 parameter bytes) cut into 2-5 pieces at random
    places, fed with random gaps: a packet is decoded iff every gap between its pieces is
    at most 1.5 ms; a dropped one leaves the reader ready for the next packet."""
    import random
    rng = random.Random(seed)
    r, t = p2.PacketReader(), 0.0
    for _ in range(60):
        params = bytes(rng.choice((0xFF, 0xFD, rng.randrange(256)))
                       for _ in range(rng.randrange(0, 300)))
        pkt = p2.build_packet(rng.randrange(0, 253), p2.INST_WRITE, params)
        cuts = sorted(rng.sample(range(1, len(pkt)), rng.randrange(1, 5)))
        pieces = [pkt[a:b] for a, b in zip([0, *cuts], [*cuts, len(pkt)])]
        gaps = [rng.choice((0.0, 0.0005, 0.0014, 0.0016, 0.003, 0.02)) for _ in pieces[1:]]
        got = r.feed(pieces[0], now=t)
        for piece, gap in zip(pieces[1:], gaps):
            t += gap
            got += r.feed(piece, now=t)
        want = [p2.Packet(pkt[4], p2.INST_WRITE, params)] if max(gaps) <= \
            p2.BYTE_GAP_TIMEOUT else []
        assert got == want, (gaps, len(pkt))
        t += 0.01                                  # a quiet bus between packets
        assert r.feed(p2.build_packet(1, p2.INST_PING), now=t) == [
            p2.Packet(1, p2.INST_PING, b"")]


def test_model_table_and_error_decoding():
    for name in ("XM430-W350", "XM430-W210", "XH430-W350", "XM540-W270", "MX-64", "MX-106"):
        m = model_by_name(name)
        assert model_by_number(m.number) is m
        assert 0.0 < m.torque_constant and 0.0 < m.current_unit < 0.01
    assert model_by_number(29) is None  # MX-28 1.0 is not supported
    with pytest.raises(ValueError, match="unsupported Dynamixel model 'AX-12'"):
        model_by_name("AX-12")
    assert decode_hardware_error(0b110101) == [
        "input_voltage", "overheating", "electrical_shock", "overload"]
    assert decode_hardware_error(0b1000) == ["motor_encoder"]
    assert REGISTERS["goal_position"].address == 116
    assert REGISTERS["present_position"].address == 132
    assert set(MODELS) >= {"XM430-W350", "MX-106"}


def test_config_from_description_and_conversions():
    desc = load_description()
    cfg = bus_config_from_description(desc)
    assert cfg.names == [f"joint{i}" for i in range(1, 10)] + ["gripper"]
    assert cfg.ids == list(range(1, 11))
    assert [j.model.name for j in cfg.joints][:3] == ["MX-106", "MX-106", "MX-64"]
    grip = cfg.joints[-1]
    assert grip.mode == "current_based_position" and grip.hold_effort == desc.gripper.grip_effort
    j = JointServo("j", 1, model_by_name("XM430-W350"), -1, 0.1, -1.0, 1.0, 2.0)
    for q in (-1.0, -0.3, 0.0, 0.77, 1.0):
        assert j.ticks_to_rad(j.rad_to_ticks_float(q)) == pytest.approx(q, abs=1e-12)
    lo, hi = j.tick_limits
    assert -1.0 <= j.ticks_to_rad(lo) <= 1.0 and -1.0 <= j.ticks_to_rad(hi) <= 1.0
    assert not -1.0 <= j.ticks_to_rad(lo - 1) <= 1.0
    assert not -1.0 <= j.ticks_to_rad(hi + 1) <= 1.0
    with pytest.raises(ConfigError, match="outside one servo turn"):
        JointServo("k", 2, model_by_name("MX-64"), 1, 0.0, -4.0, 1.0, 1.0)
    with pytest.raises(ConfigError, match="direction"):
        JointServo("k", 2, model_by_name("MX-64"), 2, 0.0, -1.0, 1.0, 1.0)


def _driver() -> DynamixelDriver:
    cfg = bus_config_from_description(load_description())
    return DynamixelDriver(DynamixelBus(cfg, "/nonexistent/ttyDXL"), other_joints=["rail"])


def test_commands_are_validated_and_clamped_without_a_port():
    d = _driver()
    with pytest.raises(CommandError, match="non-finite"):
        d.command(["joint1", "joint2"], [0.1, math.nan])
    with pytest.raises(CommandError, match="non-finite"):
        d.command(["joint1"], effort=[math.inf])
    with pytest.raises(CommandError, match=r"unknown joint\(s\) \['elbow'\]"):
        d.command(["joint1", "elbow"], [0.1, 0.2])
    assert d.command(["rail"], [0.5]).clamped == []   # another driver's joint: ignored
    with pytest.raises(CommandError, match="duplicate"):
        d.command(["joint1", "joint1"], [0.1, 0.2])
    with pytest.raises(CommandError, match="2 positions"):
        d.command(["joint1"], [0.1, 0.2])
    with pytest.raises(CommandError, match="must be numbers"):
        d.command(["joint1", "joint2"], [0.1, "up"])
    with pytest.raises(CommandError, match="must be numbers"):
        d.command(["joint1"], effort=[None])
    d.command(["joint2", "joint3"], np.array([0.2, 0.1]))      # numpy arrays are fine
    assert d.goal_position[1] == 0.2 and d.goal_position[2] == 0.1
    assert d.goal_position[0] == 0.0  # nothing applied by the rejected commands
    rep = d.command(["joint1", "rail", "gripper"], [10.0, 0.3, -1.0])
    assert rep.clamped == ["joint1", "gripper"]
    assert d.goal_position[0] == d.upper[0] and d.goal_position[-1] == 0.0
    rep = d.command(["joint3"], effort=[100.0])
    assert rep.effort_clamped == ["joint3"] and d.control[2] == "current"
    d.command(["joint4"], [0.2], [1.5])
    assert d.control[3] == "current_based_position" and d.goal_effort[3] == 1.5


def test_nan_in_any_joint_rejects_the_whole_message_even_another_drivers():
    # issue 17: {joint1: 0.9, rail: NaN} moved joint1; the contract (docs/architecture.md)
    # rejects a message with NaN/inf whole, whatever joint carries it
    d = _driver()
    for pos, eff in (([0.9, math.nan], []), ([0.9, 0.1], [0.5, math.inf]),
                     ([], [0.5, -math.inf])):
        with pytest.raises(CommandError, match=r"non-finite setpoint for \['rail'\]") as info:
            d.command(["joint1", "rail"], pos, eff)
        assert info.value.reason == "non_finite"
    assert d.goal_position[0] == 0.0 and d.control[0] == "current_based_position"


def test_effort_zero_means_the_default_limit_and_position_classes_share_one_mode():
    """docs/architecture.md, joint_command: effort 0 (or none) with a position = no extra
    limit, the joint's default limit; every position-class command is current-based
    position; a position-only command after a position+effort one has the default limit."""
    d = _driver()
    default = d.max_effort[3]
    grip = d.config.index("gripper")
    d.command(["joint4", "gripper"], [0.2, 0.5], [0.0, -0.0])
    assert d.control[3] == d.control[grip] == "current_based_position"
    assert d.goal_effort[3] == default > 1.0
    assert d.goal_effort[grip] == load_description().gripper.grip_effort
    d.command(["joint4"], [0.2], [-1.5])           # the sign of a limit does not matter
    assert d.goal_effort[3] == 1.5 and d.control[3] == "current_based_position"
    d.command(["joint4"], [0.3])                    # position only: back to the default
    assert d.goal_effort[3] == default and d.control[3] == "current_based_position"
    d.command(["joint4"], effort=[0.0])             # effort only 0: zero torque
    assert d.control[3] == "current" and d.goal_effort[3] == 0.0
    with pytest.raises(CommandError) as info:
        d.command(["joint4", "joint4"], [0.1, 0.1])
    assert info.value.reason == "duplicate"


def test_reason_throttle_is_per_reason():
    from hyperarm_driver.log_throttle import ReasonThrottle
    t = ReasonThrottle(1.0)
    assert t.allow("duplicate", now=0.0) and not t.allow("duplicate", now=0.4)
    assert t.allow("unknown_joint", now=0.5)       # another reason is not hidden
    assert not t.allow("duplicate", now=0.9) and t.suppressed("duplicate") == 2
    assert t.allow("duplicate", now=1.0) and t.suppressed("duplicate") == 0
    with pytest.raises(ValueError):
        ReasonThrottle(math.nan)


def test_bus_goal_conversion_clamps_into_tick_limits():
    cfg = bus_config_from_description(load_description())
    bus = DynamixelBus(cfg, "/nonexistent")
    q = np.array([100.0, -100.0] + [0.0] * 8)
    t = bus.goal_ticks(q)
    assert t[0] == cfg.joints[0].tick_limits[1] and t[1] == cfg.joints[1].tick_limits[0]
    assert t[2] == 2048
    c = bus.goal_current(np.array([1e3] + [0.0] * 9))
    assert c[0] == cfg.joints[0].model.current_limit
    with pytest.raises(PortOpenError, match="baud rate 12345"):
        DynamixelBus(cfg, "/dev/null", 12345)


def _status(bus: EmulatedBus, pkt: bytes) -> list[p2.Packet]:
    return p2.PacketReader().feed(b"".join(bus.feed(pkt, now=0.0)))


def test_emulated_servo_enforces_firmware_rules():
    bus = EmulatedBus([EmulatedServo(1, model_by_name("XM430-W350"))])
    (ping,) = _status(bus, p2.build_packet(1, p2.INST_PING))
    assert ping.params[1] | ping.params[2] << 8 == 1020
    # goal outside Min/Max Position Limit: Data Limit Error, not applied
    _status(bus, p2.build_packet(1, p2.INST_WRITE, bytes([48, 0]) + (3000).to_bytes(4, "little")))
    (st,) = _status(bus, p2.build_packet(1, p2.INST_WRITE, bytes([116, 0])
                                         + (3500).to_bytes(4, "little")))
    assert st.error == p2.ERR_DATA_LIMIT and bus.servos[1].get("goal_position") == 2048
    # EEPROM with torque on: Access Error
    _status(bus, p2.build_packet(1, p2.INST_WRITE, bytes([64, 0, 1])))
    (st,) = _status(bus, p2.build_packet(1, p2.INST_WRITE, bytes([11, 0, 0])))
    assert st.error == p2.ERR_ACCESS and bus.servos[1].get("operating_mode") == 3
    # overload: torque off, alert bit in every status, torque on refused
    bus.servos[1].raise_error(0x20)
    (st,) = _status(bus, p2.build_packet(1, p2.INST_WRITE, bytes([64, 0, 1])))
    assert st.error == p2.ERRBIT_ALERT | p2.ERR_RESULT_FAIL
    assert bus.servos[1].get("torque_enable") == 0
    # unknown instruction
    (st,) = _status(bus, p2.build_packet(1, 0x77))
    assert st.error & 0x7F == p2.ERR_INSTRUCTION


def test_emulated_bus_watchdog_stops_a_torque_servo_on_a_silent_bus():
    bus = EmulatedBus([EmulatedServo(1, model_by_name("XM430-W350"))])
    s = bus.servos[1]

    def write(t, addr, data):
        return bus.feed(p2.build_packet(1, p2.INST_WRITE, bytes([addr, 0]) + data), now=t)
    write(0.0, 11, bytes([0]))                           # current mode
    write(0.0, 98, bytes([5]))                           # armed: 100 ms
    write(0.0, 102, (200).to_bytes(2, "little"))         # goal current
    write(0.0, 64, bytes([1]))                           # torque on
    for t in (0.05, 0.1, 0.15):                          # traffic keeps it armed
        write(t, 102, (200).to_bytes(2, "little"))
    bus.advance(0.24)
    assert s.get("bus_watchdog") == 5 and s.get("goal_current") == 200
    bus.advance(0.3)                                     # 150 ms without a packet
    assert s.get("bus_watchdog") == -1 and s.get("goal_current") == 0
    (st,) = p2.PacketReader().feed(b"".join(write(0.31, 102, (100).to_bytes(2, "little"))))
    assert st.error == p2.ERR_DATA_RANGE and s.get("goal_current") == 0   # goals read-only
    write(0.32, 98, bytes([0]))                          # cleared
    write(0.33, 102, (100).to_bytes(2, "little"))
    assert s.get("bus_watchdog") == 0 and s.get("goal_current") == 100


def test_emulated_bus_instructions_byte_exact():
    bus = EmulatedBus([EmulatedServo(1, model_by_name("XM430-W210")),
                       EmulatedServo(2, model_by_name("XM540-W270"))])
    # broadcast ping: both answer, in ID order, with their model numbers
    got = _status(bus, p2.build_packet(p2.BROADCAST_ID, p2.INST_PING))
    assert [(pk.id, pk.params[1] | pk.params[2] << 8) for pk in got] == [(1, 1030), (2, 1120)]
    # SYNC WRITE goal positions, then SYNC READ and BULK READ them back
    _status(bus, p2.build_packet(p2.BROADCAST_ID, p2.INST_SYNC_WRITE, bytes([116, 0, 4, 0])
                                 + bytes([1]) + (1000).to_bytes(4, "little")
                                 + bytes([2]) + (3000).to_bytes(4, "little")))
    got = _status(bus, p2.build_packet(p2.BROADCAST_ID, p2.INST_SYNC_READ,
                                       bytes([116, 0, 4, 0, 1, 2])))
    assert [int.from_bytes(pk.params[1:], "little") for pk in got] == [1000, 3000]
    got = _status(bus, p2.build_packet(p2.BROADCAST_ID, p2.INST_BULK_READ,
                                       bytes([2, 116, 0, 4, 0, 1, 0, 0, 2, 0])))
    assert [(pk.id, int.from_bytes(pk.params[1:], "little")) for pk in got] == [(2, 3000),
                                                                               (1, 1030)]
    # FAST SYNC READ: one packet, ID 0xFE, segments ERR ID DATA CRC, running CRC
    (raw,) = bus.feed(p2.build_packet(p2.BROADCAST_ID, p2.INST_FAST_SYNC_READ,
                                      bytes([116, 0, 4, 0, 1, 2])), now=0.0)
    assert raw[4] == 0xFE and raw[7] == 0x55 and len(raw) == 8 + 2 * (4 + 4)
    assert raw[9] == 1 and int.from_bytes(raw[10:14], "little") == 1000
    assert raw[14] | raw[15] << 8 == p2.crc16(raw[:14])
    assert raw[17] == 2 and raw[-2] | raw[-1] << 8 == p2.crc16(raw[:-2])
    # an instruction with a bad CRC: a CRC Error status (Protocol 2.0 error 0x03), no action
    bad = bytearray(p2.build_packet(1, p2.INST_WRITE, bytes([65, 0, 1])))
    bad[-1] ^= 0xFF
    (st,) = _status(bus, bytes(bad))
    assert st.error == p2.ERR_CRC and bus.reader.crc_errors == 1
    assert bus.servos[1].get("led") == 0
    # REBOOT: status first, then RAM reset (error cleared, torque off) and silent 50 ms
    bus.servos[1].raise_error(0x08)
    (st,) = _status(bus, p2.build_packet(1, p2.INST_REBOOT))
    assert st.error == p2.ERRBIT_ALERT
    assert bus.servos[1].get("hardware_error_status") == 0
    assert bus.feed(p2.build_packet(1, p2.INST_PING), now=0.0) == []
    assert len(bus.feed(p2.build_packet(1, p2.INST_PING), now=1.0)) == 1


def test_ftdi_latency_timer_is_read_through_symlinks(tmp_path):
    sysfs = tmp_path / "sys"
    (sysfs / "ttyUSB0").mkdir(parents=True)
    (sysfs / "ttyUSB0" / "latency_timer").write_text("16\n")
    dev = tmp_path / "ttyUSB0"
    dev.touch()
    (tmp_path / "dynamixel").symlink_to(dev)
    assert ftdi_latency_timer(str(tmp_path / "dynamixel"), str(sysfs)) == 16
    assert ftdi_latency_timer("/dev/pts/0", str(sysfs)) is None


def test_emulator_lockstep_moves_the_servos_per_goal_sync_write():
    bus = EmulatedBus([EmulatedServo(1, model_by_name("XM430-W350"))])
    s = bus.servos[1]
    bus.feed(p2.build_packet(1, p2.INST_WRITE, bytes([64, 0, 1])), now=0.0)   # torque on
    bus.set_lockstep(0.01)
    goal = p2.build_packet(p2.BROADCAST_ID, p2.INST_SYNC_WRITE, bytes([116, 0, 4, 0, 1])
                           + (3000).to_bytes(4, "little"))
    bus.feed(goal, now=0.0)
    after_one = s.pos
    bus.advance(100.0)                        # the wall clock does not move them
    assert s.pos == after_one and 2048 < after_one < 3000
    for _ in range(200):                      # 2 s of servo time: at the goal
        bus.feed(goal, now=0.0)
    assert round(s.pos) == 3000
    with pytest.raises(ValueError):
        bus.set_lockstep(0.0)


def test_brake_law_before_a_limit_in_current_mode():
    """issue 17: full torque against the motion inside a velocity-dependent margin, no torque
    toward the limit when slow there, a fading torque over limit_ramp before the margin."""
    from hyperarm_driver.dynamixel.bus import BusState
    d = _driver()
    n = len(d.names)
    up = d.upper[3]

    def guard(q: float, v: float, e: float) -> float:
        pos, vel = np.zeros(n), np.zeros(n)
        pos[3], vel[3] = q, v
        z = np.zeros(n)
        d.state = BusState(0.0, pos, vel, z, z, z.astype(int), z, z, z.astype(int), z,
                           np.ones(n, dtype=bool))
        d.control[3] = "current"
        effort = np.zeros(n)
        effort[3] = e
        d._last_apply = 0.0
        d._gap = 0.01
        d._limit_guard(effort, now=0.01)
        return float(effort[3])

    m = d.max_effort[3]
    assert guard(0.0, 3.0, 1.0) == 1.0                      # far away: untouched
    margin_3 = d.limit_margin + 3.0 * 2 * 0.01 + 9.0 / (2 * d.brake_decel)
    assert guard(up - margin_3 + 0.01, 3.0, 1.0) == -m      # inside the margin at 3 rad/s
    assert guard(up - margin_3 - 0.01, 3.0, 1.0) > 0.0      # just outside: not yet
    assert guard(up - 0.002, 0.01, 1.0) == 0.0              # slow at the limit: no push
    assert guard(up - 0.002, 0.01, -1.0) == -1.0            # pulling away is fine
    half = up - d.limit_margin - d.limit_ramp / 2
    assert guard(half, 0.0, 1.0) == pytest.approx(0.5)      # fading over the ramp
    assert guard(d.lower[3] + 0.002, 0.0, -1.0) == 0.0      # the lower limit alike


@pytest.mark.parametrize("acc_raw", [0, 27, 80])
def test_emulated_servo_runs_the_velocity_based_trapezoid(acc_raw):
    """Position mode, Profile Velocity 3 rad/s: with Profile Acceleration a > 0 the speed
    never changes faster than a (e-Manual: 214.577 rev/min² per unit) and the servo stops on
    the goal without overshoot; 0 is a step (full speed from the first step)."""
    from hyperarm_driver.dynamixel.config import acceleration_to_raw, velocity_to_raw
    from hyperarm_driver.dynamixel.emulator import TICKS_PER_S2_PER_ACC_UNIT

    s = EmulatedServo(1, model_by_name("XM430-W350"))
    s._set("operating_mode", 3)
    s._set("profile_velocity", velocity_to_raw(3.0))
    s._set("profile_acceleration", acc_raw)
    s._set("torque_enable", 1)
    s._set("goal_position", 2048 + 1500)
    dt, vels, pos = 0.005, [0.0], []
    for _ in range(400):
        s.step(dt)
        vels.append(s.vel)
        pos.append(s.pos)
    dv = np.abs(np.diff(vels)) / dt
    if acc_raw == 0:
        assert dv[0] > 1e4                 # ticks/s² : a step to full speed
    else:
        a = acc_raw * TICKS_PER_S2_PER_ACC_UNIT
        assert dv.max() <= a * (1 + 1e-9), (dv.max(), a)
        # 10 rad/s² is 27 units (acceleration_to_raw), 1 unit = 0.3745 rad/s²
        assert acceleration_to_raw(acc_raw * 2 * math.pi * 214.577 / 3600) == acc_raw
    assert max(pos) <= 2048 + 1500 + 1e-9 and pos[-1] == pytest.approx(2048 + 1500, abs=1e-6)
