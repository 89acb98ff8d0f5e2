"""Emulator tier: the driver core through the real dynamixel-sdk over a pty to dxl_emulator
(a separate process): start-up, motion, modes, gripper, watchdog, faults, reconnect."""
from __future__ import annotations

import logging
import math
import time
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hs

from hyperarm_description.model import load_description
from hyperarm_driver.dynamixel.bus import DynamixelBus
from hyperarm_driver.dynamixel.config import (BusConfig, acceleration_to_raw,
                                              bus_config_from_description)
from hyperarm_driver.dynamixel.control_table import ACCELERATION_UNIT_RPM2
from hyperarm_driver.dynamixel.driver import DynamixelDriver
from hyperarm_driver.dynamixel.errors import (CommandError, CommError, PortOpenError,
                                               StartupError)
from hyperarm_driver.dynamixel.testing import EmulatorProcess

pytestmark = pytest.mark.emulator

DESC = load_description()
NAMES = [j.name for j in DESC.joints] + [DESC.gripper.name]


@pytest.fixture
def emu(tmp_path):
    with EmulatorProcess(workdir=tmp_path) as e:
        yield e


def mirrored_config() -> BusConfig:
    """The description's servos with some mounted mirrored and off-centre (the packaged YAML
    has direction +1 and zero offset 0 everywhere)."""
    changes = {0: (-1, 0.3), 3: (-1, -0.2), 4: (-1, 0.0), 6: (1, 0.25), 9: (-1, -0.2)}
    cfg = bus_config_from_description(DESC)
    return BusConfig(tuple(replace(j, direction=changes[i][0], zero_offset=changes[i][1])
                           if i in changes else j for i, j in enumerate(cfg.joints)))


def make_driver(emu: EmulatorProcess, config: BusConfig | None = None, **kw) -> DynamixelDriver:
    bus = DynamixelBus(config or bus_config_from_description(DESC), emu.link)
    return DynamixelDriver(bus, **kw)


def connect(drv: DynamixelDriver, timeout: float = 10.0) -> None:
    """``drv.connect()``, tried again while it fails on timeouts: the emulator is another
    process, which a loaded machine can starve past the SDK's few-ms reply timeouts."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            drv.connect()
            return
        except (CommError, StartupError) as exc:
            # (a servo that did not answer its pings in time is "missing"; a wrong model is
            # not a matter of time)
            if time.monotonic() > deadline or getattr(exc, "wrong_model", None):
                raise


def torque_on(drv: DynamixelDriver, timeout: float = 10.0) -> None:
    """``drv.set_torque(True)``, tried again while it fails on timeouts (see connect)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            drv.set_torque(True)
            return
        except CommError as exc:
            if time.monotonic() > deadline or "hardware error" in str(exc):
                raise


def torque_on_joint4(emu: EmulatorProcess, effort: float, **kw) -> DynamixelDriver:
    """A connected driver, torque on, joint4 in current mode with ``effort`` (N·m)."""
    drv = make_driver(emu, **kw)
    connect(drv)
    torque_on(drv)

    def in_current_mode(_st) -> bool:
        drv.command(["joint4"], effort=[effort])
        return servo(emu, 4)["operating_mode"] == 0
    run_until(drv, in_current_mode, 5.0, "joint4 in current mode")
    return drv


def cycle_ok(drv: DynamixelDriver, timeout: float = 3.0):
    """One successful cycle (a loaded machine may make one fail on timeouts: it is retried,
    the goals are the same)."""
    deadline = time.monotonic() + timeout
    while True:
        st = drv.cycle()
        if st is not None:
            return st
        assert time.monotonic() < deadline, f"no successful cycle: {drv.last_error}"
        time.sleep(0.01)


def run_until(drv: DynamixelDriver, cond, timeout: float, what: str, period: float = 0.01):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        st = drv.cycle()
        if st is not None and cond(st):
            return st
        time.sleep(period)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def wait_log(emu: EmulatorProcess, cond, timeout: float = 2.0) -> list:
    """The emulator's goal-write log once ``cond(log)`` holds (a sync write has no reply, so
    its bytes may still be in the pty when we ask)."""
    deadline = time.monotonic() + timeout
    while True:
        log = emu.ctl("write_log")["log"]
        if cond(log):
            return log
        if time.monotonic() > deadline:
            raise AssertionError(f"emulator write log never matched: {log[-20:]}")
        time.sleep(0.01)


def servo(emu: EmulatorProcess, sid: int) -> dict:
    return emu.ctl("state")["servos"][str(sid)]


def wait_servo(emu: EmulatorProcess, sid: int, cond, timeout: float, what: str) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        s = servo(emu, sid)
        if cond(s):
            return s
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}: {s}")
        time.sleep(0.01)


def test_startup_configures_every_servo_torque_off(emu):
    # values another tool may have left in a servo's EEPROM: they would mirror/shift the arm
    other = DynamixelBus(bus_config_from_description(DESC), emu.link)
    other.open()
    other.write(2, "drive_mode", 1)
    other.write(2, "homing_offset", 1024)
    other.close()
    assert (servo(emu, 3)["drive_mode"], servo(emu, 3)["homing_offset"]) == (1, 1024)
    drv = make_driver(emu)
    connect(drv)
    # the arm's MX(2.0) servos (IDs 1-6) do not answer Fast Sync Read, as on real hardware:
    # the driver falls back to plain Sync Read and says so
    assert drv.connected and not drv.bus.fast
    events = drv.pop_events()
    assert any(level == logging.WARNING and "Fast Sync Read (0x8A) failed" in e
               and "using plain Sync Read" in e for level, e in events), events
    assert emu.ctl("stats")["instructions"].get("0x82", 0) > 0
    for j in bus_config_from_description(DESC).joints:
        s = servo(emu, j.id)
        assert s["torque_enable"] == 0 and s["return_delay_time"] == 0
        assert s["drive_mode"] == 0 and s["homing_offset"] == 0
        assert (s["min_position_limit"], s["max_position_limit"]) == j.tick_limits
        assert s["operating_mode"] == 5   # every position-class command: current-based pos.
        assert s["profile_velocity"] > 0
        # the arm's servos get the description's acceleration (a trapezoid, as the mock
        # and host compensation assume); the gripper keeps its own register
        if j.gripper:
            assert s["profile_acceleration"] == 0
        else:
            spec = next(sp for sp in DESC.joints if sp.name == j.name)
            a = s["profile_acceleration"] * ACCELERATION_UNIT_RPM2 * 2 * math.pi / 3600
            assert s["profile_acceleration"] > 0
            assert abs(a - spec.acceleration) <= 0.5 * 0.3746, (j.name, a, spec.acceleration)
    st = drv.cycle()
    assert np.allclose(st.position, 0.0) and np.allclose(st.voltage, 12.0)


def test_startup_reports_missing_servo_and_wrong_model(tmp_path):
    with EmulatorProcess("--omit", "3", "--model", "7=XM540-W270", workdir=tmp_path) as e:
        drv = make_driver(e)
        with pytest.raises(StartupError) as info:
            drv.connect()
    msg = str(info.value)
    assert "missing: joint3 (ID 3)" in msg
    assert "joint7 (ID 7) expected XM430-W350, found XM540-W270" in msg
    assert info.value.missing == ["joint3"]
    assert info.value.wrong_model == {"joint7": ("XM430-W350", "XM540-W270")}
    assert not drv.connected


def test_emulator_survives_control_clients_that_vanish(emu):
    import select
    import socket
    for send in (b'{"op": "state"}\n', b"not json\n", b""):
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(emu.control_path)
        c.sendall(send)
        if send:    # wait for the reply, read a piece of it: closing resets the connection
            assert select.select([c], [], [], 5.0)[0]
            c.recv(10)
        c.close()
    assert emu.ctl("state")["ok"] and emu.proc.poll() is None


def test_open_error_names_the_port(tmp_path):
    drv = DynamixelDriver(DynamixelBus(bus_config_from_description(DESC),
                                       str(tmp_path / "no-such-tty")))
    with pytest.raises(PortOpenError, match="no-such-tty"):
        drv.connect()


def all_x_config() -> BusConfig:
    """The description's bus with its MX servos (IDs 1-6) replaced by XM430-W350s."""
    from hyperarm_driver.dynamixel.control_table import model_by_name
    xm = model_by_name("XM430-W350")
    cfg = bus_config_from_description(DESC)
    return BusConfig(tuple(replace(j, model=xm) if j.model.series == "MX" else j
                           for j in cfg.joints))


def test_motion_in_position_mode_and_fast_sync_read_on_x_servos(tmp_path):
    args = [a for i in range(1, 7) for a in ("--model", f"{i}=XM430-W350")]
    with EmulatorProcess(*args, workdir=tmp_path) as e:
        bus = DynamixelBus(all_x_config(), e.link)
        drv = DynamixelDriver(bus)
        connect(drv)
        assert bus.fast and not drv.pop_events()
        torque_on(drv)
        drv.command(["joint1", "joint5", "joint9"], [0.4, -0.6, 1.0])
        st = run_until(drv, lambda s: abs(s.position[0] - 0.4) < 2e-3
                       and abs(s.position[4] + 0.6) < 2e-3 and abs(s.position[8] - 1.0) < 2e-3,
                       5.0, "joints to reach their goals")
        assert np.allclose(st.position[[1, 2, 3, 5, 6, 7]], 0.0, atol=2e-3)
        stats = e.ctl("stats")["instructions"]
        assert stats.get("0x8a", 0) > 0 and stats.get("0x82", 0) == 0   # FAST SYNC READ


def test_current_mode_and_watchdog_hold(emu):
    # (the servos' Bus Watchdog as long as the effort watchdog here: this test is about the
    # latter; by default it is min(command_timeout, 0.1 s), see the tests below)
    drv = torque_on_joint4(emu, 0.5, command_timeout=0.3, bus_watchdog=0.3)
    s = servo(emu, 4)
    assert s["operating_mode"] == 0 and s["torque_enable"] == 1
    assert s["bus_watchdog"] == 15          # armed with 0.3 s / 20 ms
    kt, unit = drv.config.joints[3].model.torque_constant, drv.config.joints[3].model.current_unit
    assert s["goal_current"] == round(0.5 / kt / unit)
    def turning(st) -> bool:
        drv.command(["joint4"], effort=[0.5])
        return st.position[3] > 0.05
    st = run_until(drv, turning, 3.0, "joint4 to turn under torque")
    assert st.effort[3] == pytest.approx(0.5, rel=0.02)
    # no more effort commands: after command_timeout the joint holds in position mode
    drv.command(["joint4"], effort=[0.5])
    t_last = time.monotonic()
    st = run_until(drv, lambda s: servo(emu, 4)["operating_mode"] == 5, 2.0, "watchdog hold")
    assert time.monotonic() - t_last >= 0.3 - 0.02
    assert drv.watchdog_trips == 1
    held = servo(emu, 4)["goal_position"]
    assert servo(emu, 4)["bus_watchdog"] == 0   # not armed in position mode
    time.sleep(0.2)
    drv.cycle()
    assert servo(emu, 4)["goal_position"] == held
    assert abs(servo(emu, 4)["present_position"] - held) <= 2


def test_current_based_position_and_gripper_grip_force(emu):
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    # joint2 position with a 1.0 N·m limit -> current-based position, goal current = limit
    drv.command(["joint2"], [0.3], [1.0])
    j2 = drv.config.joints[1]
    limit = round(1.0 / j2.model.torque_constant / j2.model.current_unit)
    run_until(drv, lambda st: servo(emu, 2)["goal_current"] == limit, 3.0, "1 N·m limit")
    assert servo(emu, 2)["operating_mode"] == 5
    # gripper: open, then close onto an object at 0.4 rad: stalls with the grip current
    grip = drv.config.joints[-1]
    drv.command(["gripper"], [1.2])
    run_until(drv, lambda s: abs(s.position[-1] - 1.2) < 3e-3, 5.0, "gripper open")
    emu.ctl("obstacle", id=10, position=grip.rad_to_ticks_float(0.4))
    drv.command(["gripper"], [0.0])
    st = run_until(drv, lambda s: abs(s.position[-1] - 0.4) < 3e-3 and abs(s.effort[-1]) > 0.5,
                   5.0, "gripper stalled on the object")
    assert servo(emu, 10)["operating_mode"] == 5
    assert abs(st.effort[-1]) == pytest.approx(DESC.gripper.grip_effort, rel=0.02)
    # an explicit effort sets the closing force
    drv.command(["gripper"], [0.0], [0.3])
    st = run_until(drv, lambda s: abs(abs(s.effort[-1]) - 0.3) < 0.01, 2.0, "grip effort 0.3")
    # hold: every arm joint where it is, but the gripper keeps squeezing the object (held
    # where it is, its goal would be the object's surface: no squeeze, the object drops)
    drv.command(["joint2"], [0.0])
    drv.hold()
    assert drv.goal_position[1] == pytest.approx(drv.state.position[1])
    assert drv.goal_position[-1] == 0.0 and drv.goal_effort[-1] == pytest.approx(0.3)
    for _ in range(20):
        st = drv.cycle()
    assert abs(abs(st.effort[-1]) - 0.3) < 0.01 and abs(st.position[-1] - 0.4) < 3e-3


@pytest.mark.parametrize("bit,name", [(0, "input_voltage"), (2, "overheating"),
                                      (3, "motor_encoder"), (4, "electrical_shock"),
                                      (5, "overload")])
def test_hardware_errors_are_decoded_by_joint_and_smart_reboot(emu, bit, name):
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    emu.ctl("fault", id=6, bits=1 << bit)
    run_until(drv, lambda s: s.hardware_error[5] != 0, 1.0, "error bit")
    assert drv.hardware_errors() == {"joint6": [name]}
    with pytest.raises(Exception, match=f"joint6: {name}"):
        torque_on(drv)
    assert drv.reboot([]) == ["joint6"]        # smart reboot: only the joint in error
    st = drv.cycle()
    assert st.hardware_error.sum() == 0 and drv.hardware_errors() == {}
    assert servo(emu, 6)["torque_enable"] == 0 and servo(emu, 5)["torque_enable"] == 1
    assert drv.reboot([]) == []
    with pytest.raises(CommandError, match="unknown joint"):
        drv.reboot(["elbow"])


def test_crc_corruption_and_dropped_replies_are_retried(emu):
    drv = make_driver(emu)
    connect(drv)
    before = drv.bus.stats.retries
    emu.ctl("corrupt", count=1)
    assert drv.cycle() is not None
    emu.ctl("drop", id=4, count=1)
    assert drv.cycle() is not None
    # (both injected faults retried; a loaded machine may add timeouts, retried as well)
    assert drv.bus.stats.retries >= before + 2
    assert drv.bus.stats.failures >= 2
    # persistent corruption: the cycle fails cleanly (no exception), later cycles recover
    emu.ctl("rates", corrupt_rate=1.0)
    assert drv.cycle() is None and drv.connected and "sync read" in drv.last_error
    emu.ctl("rates", corrupt_rate=0.0)
    assert drv.cycle() is not None
    # slow replies (later than the SDK's packet timeout): cycle fails, port stays up
    # (0.25 s: later than all three attempts, ~37 ms each, so no late reply is taken)
    emu.ctl("rates", reply_delay=0.25)
    assert drv.cycle() is None and drv.connected and "no status packet" in drv.last_error
    emu.ctl("rates", reply_delay=0.0)
    # the late replies still arrive for a while; the SDK flushes stale input before each
    # request, so cycles succeed again once they are through
    run_until(drv, lambda s: True, 2.0, "a good cycle after the slow replies")
    assert drv.connected


@pytest.mark.parametrize("policy,torque", [("hold", 1), ("release", 0)])
def test_shutdown_policy(emu, policy, torque):
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    drv.command(["joint5"], effort=[0.3])
    drv.cycle()
    assert servo(emu, 5)["operating_mode"] == 0
    drv.shutdown(policy)
    assert not drv.connected
    states = emu.ctl("state")["servos"]
    assert all(states[str(i)]["torque_enable"] == torque for i in range(1, 11))
    if policy == "hold":   # the torque-controlled joint holds its position again
        assert states["5"]["operating_mode"] == 5


@pytest.mark.parametrize("policy,torque", [("hold", 1), ("release", 0)])
def test_shutdown_after_a_transaction_interrupted_by_ctrl_c(emu, policy, torque):
    """Ctrl-C raises KeyboardInterrupt inside the SDK, which leaves its port flagged busy
    (every later call: "Port is in use!"); the shutdown policy must still be applied."""
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    drv.command(["joint5"], effort=[0.3])
    drv.cycle()
    drv.bus.port.is_using = True   # the state an interrupted txRxPacket leaves behind
    drv.shutdown(policy)
    states = emu.ctl("state")["servos"]
    assert all(states[str(i)]["torque_enable"] == torque for i in range(1, 11))
    if policy == "hold":
        assert states["5"]["operating_mode"] == 5


def test_port_loss_detected_and_reconnect_with_torque_off(emu):
    drv = make_driver(emu, reconnect_period=0.1)
    connect(drv)
    torque_on(drv)
    drv.command(["joint1"], [0.2])
    drv.cycle()
    emu.ctl("disappear", seconds=0.6)
    t0 = time.monotonic()
    while drv.connected:
        drv.cycle()
        time.sleep(0.01)
        assert time.monotonic() - t0 < 0.5, "port loss not detected within 0.5 s"
    assert "lost" in drv.last_error
    diag = drv.diagnostics("dxl", 0.5)
    assert [d.level for d in diag] == [3] * 10 + [2]   # servos STALE, bus ERROR
    assert diag[-1].message.startswith("port down") and emu.link in diag[-1].message
    st = run_until(drv, lambda s: True, 5.0, "reconnect")
    assert drv.connected and drv.reconnects == 1 and not any(drv.bus.torque)
    assert all(servo(emu, i)["torque_enable"] == 0 for i in range(1, 11))
    assert st is not None


def test_port_loss_in_current_mode_the_servos_bus_watchdog_stops_it(emu):
    drv = torque_on_joint4(emu, 0.5, command_timeout=0.2, reconnect_period=0.1)
    assert servo(emu, 4)["goal_current"] > 0 and servo(emu, 4)["bus_watchdog"] == 5
    emu.ctl("disappear", seconds=1.0)        # nobody can command the servo any more
    t0 = time.monotonic()
    s = wait_servo(emu, 4, lambda s: s["bus_watchdog"] == -1, 3.0, "bus watchdog trip")
    assert s["goal_current"] == 0 and s["torque_enable"] == 1
    assert time.monotonic() - t0 < 3.0   # (not before its time: test_dxl_core, virtual time)
    # back: reconnect clears the trip, torque off; torque control works again when asked
    run_until(drv, lambda s: True, 5.0, "reconnect")
    assert servo(emu, 4)["bus_watchdog"] == 0 and servo(emu, 4)["torque_enable"] == 0
    torque_on(drv)
    drv.command(["joint4"], effort=[0.5])
    drv.cycle()
    assert servo(emu, 4)["goal_current"] > 0 and servo(emu, 4)["operating_mode"] == 0


def test_firmware_without_bus_watchdog_still_works(emu):
    emu.ctl("register", id=4, name="firmware_version", value=37)   # Bus Watchdog from v38
    drv = torque_on_joint4(emu, 0.5)
    s = servo(emu, 4)
    assert s["operating_mode"] == 0 and s["goal_current"] > 0 and s["bus_watchdog"] == 0
    assert drv.bus.has_watchdog == [True] * 3 + [False] + [True] * 6
    assert servo(emu, 5)["firmware_version"] == 46
    emu.ctl("fault", id=4, bits=0x20)        # its watchdog slot reads register 70 instead
    st = run_until(drv, lambda s: s.hardware_error[3] != 0, 2.0, "overload on joint4")
    assert st.bus_watchdog[3] == 0x20


def test_a_bus_watchdog_trip_is_seen_and_the_joint_held(emu):
    drv = torque_on_joint4(emu, 0.3, command_timeout=0.2)
    # the host stalls for longer than the watchdog, effort commands keep coming after it
    wait_servo(emu, 4, lambda s: s["bus_watchdog"] == -1, 3.0, "bus watchdog trip")
    drv.command(["joint4"], effort=[0.3])
    st = drv.cycle()
    assert st is not None and st.bus_watchdog[3] == -1
    assert any("bus watchdog" in e and "joint4" in e for _, e in drv.pop_events())
    s = servo(emu, 4)
    assert s["operating_mode"] == 5 and s["bus_watchdog"] == 0 and s["torque_enable"] == 1


def test_bad_commands_never_reach_the_wire(emu):
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    emu.ctl("write_log", clear=True)
    with pytest.raises(CommandError):
        drv.command(["joint1"], [math.nan])
    with pytest.raises(CommandError):
        drv.command(["bogus"], [0.1])
    rep = drv.command(["joint1", "gripper"], [5.0, -2.0])
    assert rep.clamped == ["joint1", "gripper"]
    drv.cycle()
    hi1 = drv.config.joints[0].tick_limits[1]
    log = wait_log(emu, lambda log: any(r["id"] == 1 and r["value"] == hi1 for r in log))
    j1 = [r["value"] for r in log if r["id"] == 1 and r["register"] == "goal_position"]
    g = [r["value"] for r in log if r["id"] == 10 and r["register"] == "goal_position"]
    assert j1 and j1[-1] == drv.config.joints[0].tick_limits[1]
    assert g and g[-1] == drv.config.joints[-1].tick_limits[0]
    assert all(r["accepted"] for r in log)


def _tick(direction: int, offset: float, q: float) -> float:
    """Joint angle -> servo tick, written out here independently of the driver."""
    return 2048 + (direction * q + offset) * 4096 / (2 * math.pi)


def _tick_bounds(config: BusConfig):
    """Tick range of every servo from its limits, direction and zero offset."""
    out = {}
    for j in config.joints:
        a, b = _tick(j.direction, j.zero_offset, j.lower), _tick(j.direction, j.zero_offset,
                                                                 j.upper)
        out[j.id] = (min(a, b) - 1e-6, max(a, b) + 1e-6)
    return out


def test_direction_and_zero_offset_on_the_wire(emu):
    cfg = mirrored_config()
    drv = make_driver(emu, cfg)
    connect(drv)
    bounds = _tick_bounds(cfg)
    for j in cfg.joints:
        s = servo(emu, j.id)
        assert bounds[j.id][0] <= s["min_position_limit"] < bounds[j.id][0] + 1
        assert bounds[j.id][1] - 1 < s["max_position_limit"] <= bounds[j.id][1]
    torque_on(drv)
    # joint1 (mirrored, +0.3), joint4 (mirrored, -0.2), joint7 (+0.25): goals in ticks
    targets = {0: 0.4, 3: -0.5, 6: 0.3}
    drv.command([cfg.joints[i].name for i in targets], list(targets.values()))
    st = run_until(drv, lambda s: all(abs(s.position[i] - q) < 2e-3 for i, q in targets.items()),
                   5.0, "mirrored joints at their goals")
    for i, q in targets.items():
        j = cfg.joints[i]
        assert servo(emu, j.id)["goal_position"] == round(_tick(j.direction, j.zero_offset, q))
    assert abs(st.position[1]) < 2e-3   # untouched joint stays
    # torque on a mirrored joint: positive joint torque turns the joint positive
    def turning(st) -> bool:
        drv.command(["joint5"], effort=[0.3])   # (a stream, as the effort watchdog wants)
        return st.position[4] > 0.05
    st = run_until(drv, turning, 3.0, "joint5 turning positive")
    assert servo(emu, 5)["goal_current"] < 0 and st.effort[4] == pytest.approx(0.3, rel=0.05)
    # beyond a limit a mirrored joint's torque is cut like any other's
    drv.command(["joint1"], [10.0])
    run_until(drv, lambda s: abs(s.position[0] - cfg.joints[0].upper) < 2e-3, 5.0,
              "joint1 at its upper limit")
    assert servo(emu, 1)["goal_position"] == servo(emu, 1)["min_position_limit"]


finite = hs.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
anyfloat = hs.one_of(finite, hs.sampled_from([math.nan, math.inf, -math.inf, 1e308, -0.0]))


@hs.composite
def commands(draw):
    names = draw(hs.lists(hs.sampled_from(NAMES + ["rail", "bogus"]), min_size=1, max_size=6,
                          unique=True))
    kind = draw(hs.sampled_from(["position", "effort", "both"]))
    pos = draw(hs.lists(anyfloat, min_size=len(names), max_size=len(names))) \
        if kind != "effort" else []
    eff = draw(hs.lists(anyfloat, min_size=len(names), max_size=len(names))) \
        if kind != "position" else []
    return names, pos, eff


@pytest.mark.parametrize("config", ["description", "mirrored"])
def test_property_no_generated_command_puts_a_goal_outside_limits_on_the_wire(tmp_path,
                                                                             config):
    cfg = mirrored_config() if config == "mirrored" else bus_config_from_description(DESC)
    bounds = _tick_bounds(cfg)
    with EmulatorProcess(workdir=tmp_path) as e:
        drv = make_driver(e, cfg)
        connect(drv)
        torque_on(drv)
        seen = []

        @settings(max_examples=60, deadline=None,
                  suppress_health_check=[HealthCheck.function_scoped_fixture,
                                         HealthCheck.too_slow])
        @given(commands())
        def check(cmd):
            names, pos, eff = cmd
            try:
                drv.command(names, pos, eff)
            except CommandError:
                pass
            assert cycle_ok(drv) is not None
            goals: list = []
            deadline = time.monotonic() + 2.0   # the sync write may still be in the pty
            while not goals and time.monotonic() < deadline:
                log = e.ctl("write_log", clear=True)["log"]
                goals = [r for r in log if r["register"] == "goal_position"]
            assert goals, "no goal positions on the wire"
            for r in goals:
                lo, hi = bounds[r["id"]]
                assert lo <= r["value"] <= hi, f"goal {r} outside [{lo:.1f}, {hi:.1f}]"
                assert r["accepted"]
            seen.append(len(goals))

        check()
        assert len(seen) >= 20


def test_silent_bus_is_detected_without_losing_the_port(emu):
    drv = make_driver(emu)
    connect(drv)
    assert cycle_ok(drv) is not None and drv.silent_for() < 0.2
    emu.ctl("rates", drop_rate=1.0)    # servos powered off: the port works, nobody answers
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.7:
        assert drv.cycle() is None
    assert drv.connected and drv.silent_for() > 0.5
    assert "no status packet" in drv.last_error
    bus = drv.diagnostics("dxl", 0.7)[-1]
    assert (bus.name, bus.level) == ("dxl: bus", 2) and "no valid reply" in bus.message
    assert float(dict(bus.values)["error_rate"]) > 0.0 and dict(bus.values)["connected"] == "True"
    emu.ctl("rates", drop_rate=0.0)
    assert drv.cycle() is not None and drv.silent_for() < 0.2


def test_torque_state_is_read_from_the_servo(emu):
    """issue 17: after an overload the servo turns its own torque off (e-Manual, Shutdown
    (63)); the driver reports what the servo says, not what it last wrote."""
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    drv.cycle()
    drv.pop_events()
    emu.ctl("fault", id=3, bits=0x20)          # overload: in the Shutdown mask
    run_until(drv, lambda s: not s.torque[2], 2.0, "joint3 torque off in the state")
    assert servo(emu, 3)["torque_enable"] == 0
    assert drv.bus.torque == [True, True, False] + [True] * 7
    torque = {d.name: dict(d.values)["torque"] for d in drv.diagnostics("dxl", 1.0)[:-1]}
    assert torque["dxl: joint3"] == "off" and torque["dxl: joint2"] == "on"
    events = drv.pop_events()
    assert any(level == logging.ERROR and "joint3 (overload)" in e for level, e in events)
    # a command for it is accepted but reported: its torque is off
    assert drv.command(["joint3", "joint2"], [0.1, 0.1]).torque_off == ["joint3"]


def _switch_log(log: list, sid: int) -> tuple[int, list]:
    """(torque-off count, cycles a torque-off of servo ``sid`` lasted) from a write log in
    arrival order; a cycle boundary is a SYNC WRITE (0x83) of the goals."""
    offs, spans, open_cycles = 0, [], None
    for r in log:
        if r["inst"] == 0x83 and r["register"] == "goal_position" and r["id"] == sid:
            if open_cycles is not None:
                open_cycles += 1
        if r["id"] == sid and r["register"] == "torque_enable":
            if r["value"] == 0:
                offs, open_cycles = offs + 1, 0
            elif open_cycles is not None:
                spans.append(open_cycles)
                open_cycles = None
    assert open_cycles is None, "a joint was left torque-off"
    return offs, spans


def test_alternating_command_kinds_switch_modes_rarely_and_briefly(emu):
    """issue 17: each operating-mode switch turns the torque off for a few ms. Position-class
    commands share current-based position; only effort-only <-> position switches (to 0 and
    back to 5), and a switch never leaves the torque off past the cycle it happens in."""
    drv = make_driver(emu, command_timeout=10.0)   # (the effort watchdog is not under test)
    connect(drv)
    torque_on(drv)
    drv.cycle()
    # lockstep: 10 ms of servo time per cycle, so that a stall of this test process (a loaded
    # machine) cannot trip a Bus Watchdog: this test is about the switches the driver makes
    emu.ctl("lockstep", dt=0.01)
    emu.ctl("write_log", clear=True)
    kinds = ["position", "both", "position", "both", "effort", "effort", "both", "position",
             "effort", "position"]
    switches = sum(a != b and "effort" in (a, b) for a, b in zip(kinds, kinds[1:]))
    cycles = 3 * len(kinds)
    for k in range(cycles):
        kind = kinds[k // 3]
        q, e = [0.1 * (k % 2), -0.1], [0.2, -0.2]
        if kind == "position":
            drv.command(["joint4", "joint6"], q)
        elif kind == "both":
            drv.command(["joint4", "joint6"], q, [1.0, 0.0])
        else:
            drv.command(["joint4", "joint6"], effort=e)
        assert cycle_ok(drv) is not None
    log = wait_log(emu, lambda log: sum(r["inst"] == 0x83 and r["id"] == 4
                                        and r["register"] == "goal_position"
                                        for r in log) >= cycles)
    for sid in (4, 6):
        offs, spans = _switch_log(log, sid)
        assert offs == switches, (sid, offs, switches)
        # back on before the next cycle's goals (one cycle later if a transaction of the
        # switch was lost: then the next cycle finishes it)
        assert len(spans) == switches and all(n <= 1 for n in spans), spans
        modes = [r["value"] for r in log if r["id"] == sid and r["register"] == "operating_mode"]
        modes = [m for k, m in enumerate(modes) if k == 0 or m != modes[k - 1]]   # (retries)
        assert modes == [0, 5] * (switches // 2)
    # position-only after position+effort: current-based position, default limit again
    j4 = drv.config.joints[3]
    drv.command(["joint4"], [0.2], [1.0])
    drv.cycle()
    drv.command(["joint4"], [0.2])
    drv.cycle()
    s = wait_servo(emu, 4, lambda s: s["goal_current"] == j4.model.current_limit, 2.0,
                   "default current limit")
    assert s["operating_mode"] == 5 and s["torque_enable"] == 1


def test_torque_mode_brakes_before_the_limits_in_a_fuzz(emu):
    """issue 17: in current mode the servo ignores its position limits; the driver brakes
    with a margin that grows with the velocity so that, whatever torques are commanded, no
    joint goes more than 10 ticks past a limit. The emulator runs in lockstep (10 ms of servo
    motion per cycle): this tests the brake, not how this machine schedules the test (a
    stalled host is the servos' Bus Watchdog's business, tested above)."""
    drv = make_driver(emu, mirrored_config())
    cfg = drv.config
    connect(drv)
    picks = {3: 1, 4: -1, 7: 1, 0: -1}            # joint index -> limit side it starts near
    for i, side in picks.items():
        j = cfg.joints[i]
        q0 = j.upper - 0.6 if side > 0 else j.lower + 0.6   # room to get up to speed
        emu.ctl("set", id=j.id, position=j.rad_to_ticks_float(q0))
    drv.cycle()
    torque_on(drv)
    emu.ctl("lockstep", dt=0.01)
    for i in picks:
        emu.ctl("overshoot", id=cfg.joints[i].id)
    rng = np.random.default_rng(17)
    names = [cfg.joints[i].name for i in picks]
    closest = {i: math.inf for i in picks}
    effort = np.zeros(len(picks))
    t = time.monotonic()
    good = 0
    for _ in range(2000):     # 400 good cycles: 4 s of servo time (failed ones come on top)
        if good >= 400:
            break
        t += 0.01
        if rng.random() < 0.15:                  # new random torques, mostly toward a limit
            side = np.array(list(picks.values())) * np.where(rng.random(len(picks)) < 0.85,
                                                             1, -1)
            effort = side * rng.uniform(0.3, 1.0, len(picks)) * drv.max_effort[list(picks)]
        drv.command(names, effort=list(effort), now=t)
        st = drv.cycle(now=t)
        if st is not None:
            good += 1
            for i in picks:
                closest[i] = min(closest[i], cfg.joints[i].upper - st.position[i],
                                 st.position[i] - cfg.joints[i].lower)
    assert good >= 400        # (the brake law itself: test_dxl_core, deterministic)
    for i in picks:
        assert closest[i] < 0.1, (cfg.joints[i].name, closest[i])   # the limits were tested
        over = emu.ctl("overshoot", id=cfg.joints[i].id)["ticks"]
        assert over is not None and over <= 10.0, (cfg.joints[i].name, over)


def test_the_configured_baud_rate_is_used(tmp_path):
    """Servos at 57600 bit/s (Baud Rate 1) answer a driver at 57600 and nobody at the SDK's
    default 1 Mbit/s: the emulator hears only at each servo's own rate."""
    cfg = bus_config_from_description(DESC)
    spec = ",".join(f"{j.id}:{j.model.name}@57600" for j in cfg.joints)
    with EmulatorProcess("--servos", spec, workdir=tmp_path) as e:
        drv = DynamixelDriver(DynamixelBus(cfg, e.link, baud=57600))
        connect(drv)
        assert cycle_ok(drv) is not None and drv.bus.baud == 57600
        drv.shutdown("release")
        fast = DynamixelDriver(DynamixelBus(cfg, e.link, baud=1_000_000))
        with pytest.raises(StartupError, match="missing: joint1 .ID 1., joint2"):
            fast.connect()


def test_a_mode_switch_interrupted_by_a_lost_reply_gets_its_torque_back(emu):
    """A mode switch is torque off -> mode -> goals -> torque on; if a transaction fails
    midway, the joint must not stay limp: the next cycle finishes the switch."""
    drv = make_driver(emu)
    connect(drv)
    torque_on(drv)
    st = drv.cycle()
    emu.ctl("drop", id=4, count=3)            # torque-off runs, its replies are all lost
    with pytest.raises(CommError):
        drv.bus.set_mode(3, 0, int(st.ticks[3]), 0)
    assert drv.bus.pending_on[3] and servo(emu, 4)["torque_enable"] == 0
    drv.command(["joint4"], effort=[0.2])
    run_until(drv, lambda st: st.torque[3], 3.0, "torque back on joint4")
    s = servo(emu, 4)
    assert s["torque_enable"] == 1 and s["operating_mode"] == 0 and not drv.bus.pending_on[3]


def test_a_failed_read_stops_the_torque_of_joints_in_current_mode(emu):
    """No state, no brake before a limit: a joint in current mode stops pushing (goal current
    0) while the sync read fails, and gets its torque command again when it is back."""
    drv = torque_on_joint4(emu, 0.5)
    assert servo(emu, 4)["goal_current"] > 0
    emu.ctl("rates", drop_rate=1.0)          # the servos stop answering
    drv.command(["joint4"], effort=[0.5])
    assert drv.cycle() is None
    s = wait_servo(emu, 4, lambda s: s["goal_current"] == 0, 2.0, "goal current 0")
    assert s["operating_mode"] == 0 and s["torque_enable"] == 1
    emu.ctl("rates", drop_rate=0.0)

    def pushing(_st) -> bool:
        drv.command(["joint4"], effort=[0.5])
        return servo(emu, 4)["goal_current"] > 0
    run_until(drv, pushing, 3.0, "torque command back")


@pytest.mark.parametrize("a, raw", [(10.0, 27), (0.3745, 1), (1e-6, 1), (1e9, 32767)])
def test_acceleration_to_raw(a, raw):
    # 214.577 rev/min² per unit (e-Manual): 10 rad/s² = 5729.6 rev/min² = 26.7 units
    assert acceleration_to_raw(a) == raw
