"""PMAC client, rail axis and driver core against the emulator over loopback TCP."""
from __future__ import annotations

import socket
import time

import pytest

from hyperarm_description.model import load_description
from hyperarm_driver.pmac import protocol as proto
from hyperarm_driver.pmac.axis import RailAxis, RailConfig
from hyperarm_driver.pmac.client import PmacClient
from hyperarm_driver.pmac.driver import ERROR, OK, WARN, RailDriver
from hyperarm_driver.pmac.emulator import PmacEmulator
from hyperarm_driver.pmac.errors import (PmacCommandError, PmacLinkError, PmacProtocolError,
                                         PmacTimeoutError,
                                         RailCommandError)

pytestmark = pytest.mark.emulator

CPM = 200000.0     # counts per metre of the packaged description


@pytest.fixture
def emu():
    # power-on 1 cm past the home switch; overtravel switches at ±0.1 m
    with PmacEmulator(start_position=2000, limits=(-0.1 * CPM, 0.1 * CPM)) as e:
        yield e


@pytest.fixture
def client(emu):
    c = PmacClient("127.0.0.1", emu.port, timeout=0.2)
    yield c
    c.close()


@pytest.fixture
def axis(client) -> RailAxis:
    ax = RailAxis(client, RailConfig.from_rail(load_description(variant="rail_arm").rail))
    ax.configure()
    client.command("I123=-20")       # home search: 20 counts/ms = 0.1 m/s toward negative
    return ax


def home(axis: RailAxis, wait_for) -> None:
    axis.enable()
    axis.home()
    wait_for(lambda: axis.status().home_complete, 5.0, what="home complete")


def settled(axis: RailAxis):
    st = axis.read()
    return st if st.status.in_position and not st.status.move_timer else None


# -- client -----------------------------------------------------------------------------------
def test_round_trip_and_multi_line_reply(client, emu) -> None:
    assert client.command("#1P") == ["2000"]
    assert client.command("#1P #1V #1F") == ["2000", "0", "0"]
    assert client.query_float("I10") == 3713991
    assert client.connects == 1 and client.commands_sent == 3
    assert 0 < client.last_round_trip < 0.2


def test_error_reply_is_an_exception_and_keeps_the_link(client) -> None:
    with pytest.raises(PmacCommandError) as err:
        client.command("#1P #1XYZ")
    assert err.value.code == 3 and err.value.partial == ("2000",)
    assert "unrecognized command" in str(err.value)
    assert client.command("#1P") == ["2000"] and client.connects == 1


def test_long_reply_is_fetched_with_getbuffer(client, emu) -> None:
    client.command("I999=7.25")
    before = emu.requests
    lines = client.command("I100..999")
    assert len(lines) == 900 and sum(len(x) + 1 for x in lines) > proto.REPLY_CHUNK
    assert (lines[0], lines[22], lines[-1]) == ("1", "32", "7.25")   # I100, I122, I999
    assert emu.requests - before >= 2                    # GETRESPONSE + at least one GETBUFFER


def test_non_ascii_command_bytes_get_err004(emu) -> None:
    with socket.create_connection(("127.0.0.1", emu.port), timeout=2.0) as s:
        s.sendall(proto.encode_request(proto.VR_DOWNLOAD, proto.Request.GETRESPONSE, b"#1P\xe9"))
        assert s.recv(100) == b"\x07ERR004\r"
        s.sendall(proto.flush_packet())
        assert s.recv(10) == b"\x18"      # one byte: the <CTRL-X> echo (I63=1)


def test_unanswered_command_times_out_then_reconnects(client, emu) -> None:
    client.command("#1P")
    emu.mute = True
    t0 = time.monotonic()
    with pytest.raises(PmacTimeoutError):
        client.command("#1P")
    assert time.monotonic() - t0 < 0.5 and not client.connected
    emu.mute = False
    assert client.command("#1P") == ["2000"] and client.connects == 2


def test_dropped_connection_is_a_link_error_then_reconnects(client, emu, wait_for) -> None:
    client.command("#1P")
    emu.drop_connections()
    with pytest.raises(PmacLinkError):
        client.command("#1P")
    assert client.command("#1P") == ["2000"] and client.connects == 2


def test_refused_connection() -> None:
    with socket.socket() as s:        # a port with nobody listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    c = PmacClient("127.0.0.1", port, timeout=0.1)
    with pytest.raises(PmacLinkError, match="cannot connect"):
        c.command("#1P")
    with pytest.raises(PmacLinkError):
        PmacClient("127.0.0.1", port, auto_reconnect=False).command("#1P")


# -- axis ---------------------------------------------------------------------------------------
def test_configure_sets_ivariables(axis, emu) -> None:
    m = emu.motor(1)
    assert m.ivars[22] == pytest.approx(100.0) and m.ivars[19] == pytest.approx(0.2)
    assert (m.ivars[13], m.ivars[14]) == (300000.0, -300000.0)


def test_homing_jog_and_stop(axis, emu, wait_for) -> None:
    st = axis.read()
    assert st.position == pytest.approx(0.01) and not st.status.home_complete
    home(axis, wait_for)
    st = wait_for(lambda: settled(axis), 3.0, what="settled after homing")
    assert st.position == pytest.approx(0.0, abs=1e-6) and st.status.home_complete
    axis.jog_to(0.05)
    moving = wait_for(lambda: (s := axis.read()).velocity > 0.01 and s, 2.0, what="moving")
    assert moving.status.move_timer and moving.following_error > 0
    st = wait_for(lambda: settled(axis), 3.0, what="at 0.05 m")
    assert st.position == pytest.approx(0.05, abs=1e-6)
    axis.jog_to(-0.08)
    wait_for(lambda: axis.read().position < 0.03, 2.0, what="moving back")
    axis.stop()
    st = wait_for(lambda: settled(axis), 2.0, what="stopped")
    assert -0.08 + 1e-3 < st.position < 0.03 and st.status.amp_enabled


def test_kill_and_enable(axis, wait_for) -> None:
    axis.enable()
    assert axis.status().amp_enabled
    axis.kill()
    st = axis.status()
    assert st.open_loop and not st.amp_enabled
    axis.enable()
    assert axis.status().amp_enabled


def test_hardware_limit_switch(axis, emu, wait_for) -> None:
    home(axis, wait_for)
    axis.jog_to(0.5)          # within the soft limits, beyond the +0.1 m switch
    st = wait_for(lambda: (s := axis.read()).status.pos_limit and s, 3.0, what="+limit")
    st = wait_for(lambda: (s := axis.read()).velocity == 0 and s, 1.0, what="stop at limit")
    assert st.position == pytest.approx(0.1, abs=1e-4)
    assert st.status.stopped_on_position_limit and not st.status.neg_limit
    axis.jog_to(0.3)          # further into the limit: the card does not move
    time.sleep(0.05)
    assert axis.read().position == pytest.approx(0.1, abs=1e-4)
    axis.jog_to(0.05)         # away from it: allowed
    st = wait_for(lambda: settled(axis), 3.0, what="back off the limit")
    assert st.position == pytest.approx(0.05, abs=1e-6) and not st.status.pos_limit


def test_home_search_ending_on_a_limit_fails(client, emu, wait_for) -> None:
    ax = RailAxis(client, RailConfig.from_rail(load_description(variant="rail_arm").rail))
    ax.configure()
    client.command("I123=20")          # searching away from the switch: hits +limit
    ax.enable()
    ax.home()
    st = wait_for(lambda: (s := ax.status()).pos_limit and not s.home_search and s, 5.0,
                  what="home search stopped on the limit")
    assert not st.home_complete and st.stopped_on_position_limit


def test_amplifier_fault_kills_and_blocks_enable(axis, emu, wait_for) -> None:
    home(axis, wait_for)
    axis.jog_to(0.05)
    emu.set_amp_fault(1, True)
    st = axis.status()
    assert st.amp_fault and not st.amp_enabled and st.faults == ["amp_fault"]
    axis.enable()                              # fault line still active: stays killed
    assert not axis.status().amp_enabled
    emu.set_amp_fault(1, False)
    axis.enable()
    st = axis.status()
    assert st.amp_enabled and not st.amp_fault and st.home_complete


def test_following_error_warning_and_fatal(axis, emu, wait_for) -> None:
    home(axis, wait_for)
    emu.set_disturbance(1, 1500)               # > Ixx12/16 = 1000 counts, < Ixx11/16 = 2000
    st = axis.read()
    assert st.status.warning_following_error and not st.status.fatal_following_error
    assert st.following_error == pytest.approx(1500 / CPM)
    emu.set_disturbance(1, 2500)               # > Ixx11/16: fatal, killed
    st = axis.read()
    assert st.status.fatal_following_error and not st.status.amp_enabled
    assert st.following_error == 0.0           # open loop
    emu.set_disturbance(1, 0)
    axis.enable()
    assert not axis.status().fatal_following_error


def test_out_of_range_targets_never_reach_the_card(axis, emu) -> None:
    before = emu.requests
    for bad in (1.6, -1.51, float("nan"), float("inf")):
        with pytest.raises(RailCommandError):
            axis.jog_to(bad)
    assert emu.requests == before


# -- driver core --------------------------------------------------------------------------------
@pytest.fixture
def driver(axis):
    events: list[tuple[str, str]] = []
    d = RailDriver(axis, rate=100.0, reconnect_period=0.1,
                   log=lambda level, msg: events.append((level, msg)))
    d.events = events
    d.start()
    yield d
    d.stop()


def test_driver_refuses_motion_until_homed(driver, emu, wait_for) -> None:
    wait_for(lambda: driver.snapshot().link_up and driver.snapshot().state, 2.0, what="link")
    with pytest.raises(RailCommandError, match="torque is off"):
        driver.set_target(0.02)
    assert driver.request("enable") == "torque on, holding position"
    with pytest.raises(RailCommandError, match="not homed"):
        driver.set_target(0.02)
    with pytest.raises(RailCommandError, match="soft limits"):
        driver.set_target(2.0)
    assert driver.snapshot().rejected_setpoints == 3
    level, msg, _ = driver.snapshot().diagnostic()
    assert level == WARN and "not homed" in msg
    assert driver.request("home") == "home search started"
    wait_for(lambda: driver.snapshot().homed, 5.0, what="homed")
    wait_for(lambda: driver.snapshot().diagnostic()[0] == OK, 2.0, what="diagnostics OK")
    driver.set_target(0.03)
    wait_for(lambda: abs(emu.motor(1).actual - emu.motor(1).ref - 0.03 * CPM) < 0.5, 3.0,
             what="emulated motor at 0.03 m")
    assert ("info", "home complete") in driver.events


@pytest.mark.parametrize("kind", ["hold", "home"])
def test_hold_or_home_right_after_a_card_kill_never_closes_the_loop(driver, emu, wait_for,
                                                                    kind) -> None:
    """Without the safety PLC (watchdog off), ``J/`` and ``HM`` close a killed motor's loop;
    a request arriving before the next poll saw the kill must be refused and the fault
    latched, not answered "holding" with the motor quietly re-enabled."""
    wait_for(lambda: driver.snapshot().link_up, 2.0, what="link")
    for trial in range(5):
        driver.request("enable")
        wait_for(lambda: emu.motor(1).closed_loop, 2.0, what="enabled")
        enables = emu.motor(1).enables
        emu.set_disturbance(1, 2500)             # a momentary fatal following error ...
        emu.set_disturbance(1, 0)                # ... gone at once
        with pytest.raises(RailCommandError, match="fatal following error"):
            driver.request(kind)
        m = emu.motor(1)
        assert not m.closed_loop and m.enables == enables, f"trial {trial}: loop closed"
        snap = driver.snapshot()
        assert snap.latched and "fatal following error" in snap.latched[0], snap.latched
        assert not snap.torque and snap.diagnostic()[0] == ERROR


def test_driver_hold_and_kill(driver, emu, wait_for) -> None:
    wait_for(lambda: driver.snapshot().link_up, 2.0, what="link")
    with pytest.raises(RailCommandError, match="torque is off"):
        driver.request("hold")
    driver.request("enable")
    assert driver.request("hold") == "holding"
    assert driver.request("kill") == "motor killed (torque off)"
    assert not emu.motor(1).closed_loop
    emu.set_amp_fault(1, True)
    with pytest.raises(RailCommandError, match="amplifier fault"):
        driver.request("enable")
    wait_for(lambda: driver.snapshot().diagnostic()[0] == ERROR, 2.0, what="ERROR level")
    emu.set_amp_fault(1, False)                  # the cause is gone: still latched
    time.sleep(0.05)
    snap = driver.snapshot()
    assert snap.latched == ("amplifier fault on the card",) and snap.diagnostic()[0] == ERROR
    assert "set_torque true" in snap.diagnostic()[1]
    assert "cleared: amplifier fault" in driver.request("enable")
    assert driver.snapshot().latched == () and driver.snapshot().torque


def test_driver_detects_link_loss_fast_and_reconnects(driver, emu, wait_for) -> None:
    wait_for(lambda: driver.snapshot().link_up, 2.0, what="link")
    driver.request("enable")
    emu.motor(1).homed = True                   # skip the home search for this test
    wait_for(lambda: driver.snapshot().homed, 2.0, what="homed seen")
    for fault in ("mute", "drop"):
        if fault == "mute":
            emu.mute = True                     # card silent: detected by the reply timeout
        else:
            emu.refuse = True                   # and reconnection attempts fail for now
            emu.drop_connections()              # connection closed: detected at once
        t0 = time.monotonic()
        wait_for(lambda: not driver.snapshot().link_up, 1.0, what=f"link loss ({fault})")
        assert time.monotonic() - t0 < 0.5
        with pytest.raises(RailCommandError, match="link down"):
            driver.set_target(0.02)
        assert driver.snapshot().diagnostic()[0] == ERROR
        emu.mute = emu.refuse = False
        wait_for(lambda: driver.snapshot().link_up, 2.0, what=f"reconnect after {fault}")
    assert driver.snapshot().reconnects == 2
    assert sum(1 for lvl, m in driver.events if lvl == "error" and "link lost" in m) == 2


def test_driver_kills_a_motion_left_over_from_before_a_link_loss(driver, emu, wait_for) -> None:
    # one torque rule (docs/architecture.md): after a reconnect torque stays off until asked
    wait_for(lambda: driver.snapshot().link_up, 2.0, what="link")
    driver.request("enable")
    emu.motor(1).homed = True
    wait_for(lambda: driver.snapshot().homed, 2.0, what="homed seen")
    emu.refuse = True
    driver.set_target(0.09)
    wait_for(lambda: emu.motor(1).vel > 0, 2.0, what="motion started")
    emu.drop_connections()
    wait_for(lambda: not driver.snapshot().link_up, 1.0, what="link loss")
    emu.refuse = False
    wait_for(lambda: driver.snapshot().link_up, 2.0, what="reconnect")
    assert not emu.motor(1).closed_loop and emu.motor(1).vel == 0     # killed at reconnect
    assert emu.motor(1).actual - emu.motor(1).ref < 0.09 * CPM - 100    # not finished
    snap = driver.snapshot()
    assert not snap.torque and snap.latched == ("link lost while torque was on",)
    with pytest.raises(RailCommandError, match="latched"):
        driver.set_target(0.05)
    assert any("it was on: killed" in m for _, m in driver.events)


def test_driver_stop_halts_a_motion_and_leaves_a_killed_motor_killed(axis, emu,
                                                                     wait_for) -> None:
    for kill in (False, True):
        d = RailDriver(axis, rate=100.0, reconnect_period=0.1)
        d.start()
        wait_for(lambda: d.snapshot().link_up, 2.0, what="link")
        d.request("enable")
        emu.motor(1).homed = True
        wait_for(lambda: d.snapshot().homed, 2.0, what="homed seen")
        if kill:
            d.request("kill")
            d.stop()
            assert not emu.motor(1).closed_loop        # shutdown did not enable it
            continue
        start = emu.motor(1).actual
        d.set_target((emu.motor(1).actual - emu.motor(1).ref) / CPM + 0.05)
        wait_for(lambda: emu.motor(1).vel != 0, 2.0, what="motion started")
        d.stop()
        wait_for(lambda: emu.motor(1).mode == "idle" and emu.motor(1).vel == 0, 2.0,
                 what="stopped")
        assert abs(emu.motor(1).actual - start) < 0.05 * CPM - 100   # short of the target
        assert emu.motor(1).closed_loop


def test_home_offset_ixx26_in_sixteenths_of_a_count(axis, client, emu, wait_for) -> None:
    client.command("I126=6400")               # 400 counts beyond the switch is the zero
    home(axis, wait_for)
    st = wait_for(lambda: settled(axis), 3.0, what="settled after homing")
    assert st.position == pytest.approx(0.0, abs=1e-6)
    assert emu.motor(1).actual == pytest.approx(400.0)     # physical: switch at 0 + 400


def test_emulator_command_line_help() -> None:
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-m", "hyperarm_driver.pmac.emulator", "--help"],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0 and "--port" in out.stdout and "127.0.0.1" in out.stdout


def test_emulator_exits_on_sigint_even_if_started_with_sigint_ignored() -> None:
    """A background job starts its children with SIGINT ignored (the launch fixture and
    users stop the emulator with SIGINT)."""
    import signal
    import subprocess
    import sys
    proc = subprocess.Popen([sys.executable, "-m", "hyperarm_driver.pmac.emulator", "--port",
                             "0"], stdout=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        assert "listening on 127.0.0.1:" in proc.stdout.readline()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10.0) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()


def test_serial_client_on_a_pty(emu) -> None:
    from hyperarm_driver.pmac.client import PmacSerialClient
    with PmacSerialClient(emu.serve_pty(), timeout=0.3) as c:
        assert c.command("#1P #1V") == ["2000", "0"]
        with pytest.raises(PmacCommandError) as err:
            c.command("#1P #1XYZ")
        assert err.value.code == 3 and err.value.partial == ("2000",)
        rail = RailAxis(c, RailConfig.from_rail(load_description(variant="rail_arm").rail))
        assert rail.read().position == pytest.approx(0.01)
        emu.mute = True
        with pytest.raises(PmacTimeoutError):
            c.command("#1P")
        emu.mute = False
        assert c.command("#1P") == ["2000"]       # reopened


# -- reply forms of a real card -------------------------------------------------------------
def test_busy_nul_is_retried_not_a_link_loss(emu) -> None:
    client = PmacClient("127.0.0.1", emu.port, timeout=1.0)   # (a loaded host: no stall)
    emu.busy = 3                                   # three NUL replies, then the answer
    assert client.command("#1P") == ["2000"]
    assert client.busy_replies == 3 and client.connects == 1
    emu.busy = 10 ** 6                             # busy for longer than the timeout
    from hyperarm_driver.pmac.errors import PmacBusyError
    with pytest.raises(PmacBusyError, match="busy"):
        client.command("#1P")
    emu.busy = 0
    assert client.command("#1P") == ["2000"]
    client.close()


def test_stx_message_then_the_reply_via_getbuffer(client, emu) -> None:
    client.command("I64=1")
    emu.send_message("HELLO FROM PLC")
    assert client.command("#1P #1V") == ["2000", "0"]
    assert list(client.messages) == ["HELLO FROM PLC"]


def test_set_communication_tags_unsolicited_messages(client, emu) -> None:
    """The card's default I64=0 mixes a PLC's SEND text into the next reply (a corrupt reply,
    taken for a link loss); the driver's set-up sets I64=1 so it comes tagged."""
    ax = RailAxis(client, RailConfig.from_rail(load_description(variant="rail_arm").rail))
    emu.globals[64] = 0.0
    ax.set_communication()
    emu.send_message("PLC5 SAYS HI")
    assert client.command("#1P #1V") == ["2000", "0"]
    assert list(client.messages) == ["PLC5 SAYS HI"]


def test_check_communication_refuses_a_card_not_set_up(client, emu) -> None:
    from hyperarm_driver.pmac.errors import RailConfigError
    ax = RailAxis(client, RailConfig.from_rail(load_description(variant="rail_arm").rail))
    client.command("I6=0")
    with pytest.raises(RailConfigError, match="I6=0"):
        ax.check_communication()
    with pytest.raises(PmacProtocolError, match="I3=1"):
        client.command("I3=1 I6=1")                 # its reply already ends with LF
    ax.set_communication()                          # I3=2 I6=1 applies to its own reply
    ax.check_communication()


# -- the safety PLC: fault latch and host watchdog (watchdog.py) ----------------------------
# The driver, the emulator and the test share one process here: a 100 ms timeout (the
# default, tested through the installed driver in test_pmac_node.py) can trip on a loaded
# 2-core test host; the assertions below are relative to the configured timeout.
WD_TIMEOUT = 0.25


@pytest.fixture
def wd_emu():
    # overtravel switches at +-1 m: room for a long, fast move
    with PmacEmulator(start_position=2000, limits=(-CPM, CPM)) as e:
        yield e


@pytest.fixture
def wd_driver(wd_emu, wait_for):
    from hyperarm_driver.pmac.watchdog import WatchdogConfig
    client = PmacClient("127.0.0.1", wd_emu.port, timeout=0.2)
    ax = RailAxis(client, RailConfig.from_rail(load_description(variant="rail_arm").rail),
                  watchdog=WatchdogConfig(timeout=WD_TIMEOUT))
    events: list[tuple[str, str]] = []
    d = RailDriver(ax, rate=100.0, reconnect_period=0.1,
                   log=lambda level, msg: events.append((level, msg)))
    d.events = events
    d.start()
    wait_for(lambda: d.snapshot().link_up, 3.0, what="link")
    d.request("enable")
    wd_emu.motor(1).homed = True
    wait_for(lambda: d.snapshot().homed, 2.0, what="homed seen")
    yield d
    d.stop()


def test_a_killed_motor_stays_killed_whatever_is_streamed(wd_driver, wd_emu, wait_for) -> None:
    import threading
    stop = threading.Event()
    refused = []

    def stream() -> None:                          # 200 Hz setpoints, as a task would
        k = 0
        while not stop.is_set():
            try:
                wd_driver.set_target(0.02 + 0.0001 * (k % 100))
            except RailCommandError as exc:
                refused.append(str(exc))
            k += 1
            time.sleep(0.005)

    t = threading.Thread(target=stream)
    t.start()
    try:
        wait_for(lambda: wd_emu.motor(1).vel != 0, 2.0, what="streamed motion")
        enables = wd_emu.motor(1).enables
        wd_emu.set_disturbance(1, 2500)            # a momentary fatal following error
        wd_emu.set_disturbance(1, 0)               # gone at once: the cause has cleared
        time.sleep(0.5)                            # ~100 setpoints streamed meanwhile
    finally:
        stop.set()
        t.join()
    m = wd_emu.motor(1)
    assert not m.closed_loop and m.enables == enables    # never closed again
    snap = wd_driver.snapshot()
    assert snap.latched and "fatal following error" in snap.latched[0]
    assert snap.diagnostic()[0] == ERROR and not snap.torque
    assert refused and all("latched" in r for r in refused[-5:])
    errors = [msg for lvl, msg in wd_driver.events if lvl == "error" and "latched" in msg]
    assert len(errors) == 1                        # logged once
    assert wd_driver.request("enable").startswith("torque on")
    assert wd_emu.motor(1).closed_loop and wd_driver.snapshot().latched == ()


def test_watchdog_stops_the_rail_when_the_link_is_cut_mid_move(wd_driver, wd_emu,
                                                              wait_for) -> None:
    wd_driver.set_target(0.9)
    cruise = wd_emu.motor(1).ivars[22] * 1e3       # counts/s, the jog speed (0.5 m/s)
    wait_for(lambda: wd_emu.motor(1).vel >= 0.999 * cruise, 3.0, what="full speed")
    wd_emu.mute = True                             # the cable is cut: nothing gets through
    m = wd_emu.motor(1)
    t_cut, v = m.now, m.vel                        # (emulator clock) speed at the cut
    wait_for(lambda: wd_emu.motor(1).vel == 0 and wd_emu.motor(1).mode == "idle", 3.0,
               what="the rail stopped by the card")
    m = wd_emu.motor(1)
    decel = v / (m.ivars[19] * 1e6)                # s, at the jog acceleration Ixx19
    assert m.motion_ended_at - t_cut <= WD_TIMEOUT + decel + 0.01
    assert m.closed_loop and m.actual - m.ref < 0.9 * CPM - 1000   # held, short of 0.9 m
    assert wd_emu.pvars[8003] == 0                 # the PLC disarmed itself
    wd_emu.mute = False
    wait_for(lambda: wd_driver.snapshot().link_up and wd_driver.snapshot().reconnects, 3.0,
               what="reconnected")
    assert not wd_emu.motor(1).closed_loop         # torque off after a reconnect


def test_a_watchdog_trip_is_counted_latched_and_named_in_refusals(wd_driver, wd_emu,
                                                                   wait_for) -> None:
    """Issue 25 item 5: a trip while the link stays up (the host's heartbeat was late by
    more than the timeout: here the card's timer is run out directly) is latched, counted in
    ``watchdog_trips`` and named in every refused setpoint (``last_rejection``); enabling
    again clears the latch, the count stays."""
    wd_driver.set_target(0.05)
    wait_for(lambda: wd_emu.motor(1).vel != 0, 2.0, what="moving")
    assert wd_driver.snapshot().watchdog_trips == 0
    with wd_emu._lock:
        wd_emu.set("I", 5111, 0)                 # the timer ran out: the PLC trips
    wait_for(lambda: wd_driver.snapshot().latched, 2.0, what="trip latched")
    snap = wd_driver.snapshot()
    assert snap.watchdog_trips == 1 and snap.latched[0].startswith("watchdog PLC tripped")
    level, message, kv = snap.diagnostic()
    assert level == ERROR and "watchdog PLC tripped" in message
    assert dict(kv)["watchdog_trips"] == "1" and dict(kv)["last_rejection"] == "none"
    with pytest.raises(RailCommandError, match="watchdog PLC tripped"):
        wd_driver.set_target(0.06)
    kv = dict(wd_driver.snapshot().diagnostic()[2])
    assert "watchdog PLC tripped" in kv["last_rejection"] and kv["rejected_setpoints"] == "1"
    wait_for(lambda: not wd_emu.motor(1).closed_loop, 2.0,
             what="killed by the driver on the latch")
    assert wd_driver.request("enable").startswith("torque on")
    assert wd_driver.snapshot().latched == () and wd_driver.snapshot().watchdog_trips == 1


@pytest.mark.parametrize("seed", range(3))
def test_a_setpoint_after_a_trip_is_caught_at_once_not_at_the_next_poll(wd_emu, wait_for,
                                                                        seed) -> None:
    """After a trip (the PLC stopped and holds the rail, disarmed) a setpoint the late
    worker sends before its next poll moves the rail with no watchdog armed. The jog's own
    line reads the armed flag: the driver latches the trip and kills the motor one round
    trip after that jog, whatever the poll period (1 s here: the old driver let the rail
    run unarmed until the next poll). Random trip instants and targets, 3 seeds."""
    import random
    from hyperarm_driver.pmac.watchdog import WatchdogConfig
    rng = random.Random(seed)
    client = PmacClient("127.0.0.1", wd_emu.port, timeout=0.5)
    ax = RailAxis(client, RailConfig.from_rail(load_description(variant="rail_arm").rail),
                  watchdog=WatchdogConfig(timeout=2.0))
    d = RailDriver(ax, rate=1.0, reconnect_period=0.1, require_homing=False)
    d.start()
    try:
        wait_for(lambda: d.snapshot().link_up, 3.0, what="link")
        d.request("enable")
        time.sleep(rng.uniform(0.0, 0.5))
        with wd_emu._lock:
            wd_emu.set("I", 5111, 0)                   # the timer runs out: the trip
        wait_for(lambda: wd_emu.pvars[8003] == 0, 2.0, what="the PLC tripped")
        assert not d.snapshot().latched               # the 1 Hz poll has not seen it yet
        t0 = time.monotonic()
        d.set_target(rng.uniform(0.05, 0.3))
        wait_for(lambda: d.snapshot().latched, 0.5, what="the trip latched with the jog")
        assert time.monotonic() - t0 < 0.5
        assert d.snapshot().latched[0].startswith("watchdog PLC tripped")
        wait_for(lambda: not wd_emu.motor(1).closed_loop, 0.5, what="killed after the jog")
        assert abs(wd_emu.motor(1).pos - 2000) < 0.002 * CPM   # < 2 mm moved unarmed
    finally:
        d.stop()
        client.close()
