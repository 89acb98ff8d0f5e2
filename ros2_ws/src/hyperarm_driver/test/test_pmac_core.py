"""PMAC core without sockets or ROS: packet format, reply parsing, status words, scaling,
soft limits, and the emulator's command interpreter."""
from __future__ import annotations

import math

import pytest

from hyperarm_description.model import load_description
from hyperarm_driver.pmac import protocol as proto
from hyperarm_driver.pmac.axis import MotorStatus, RailAxis, RailConfig, servo_period_from_i10
from hyperarm_driver.pmac.emulator import PmacEmulator
from hyperarm_driver.pmac.errors import (PmacCommandError, PmacProtocolError, RailCommandError,
                                         RailConfigError)

pytestmark = pytest.mark.core


@pytest.fixture
def config() -> RailConfig:
    return RailConfig.from_rail(load_description(variant="rail_arm").rail)


class RecordingPort:
    """Records the command lines an axis would send; answers with canned replies."""

    def __init__(self, replies: dict[str, list[str]] | None = None) -> None:
        self.sent: list[str] = []
        self.replies = replies or {}

    def command(self, command: str) -> list[str]:
        self.sent.append(command)
        if command.startswith("#1?#1J="):
            return ["880000000000"]          # status read before a jog: enabled
        return self.replies.get(command, [])


# -- protocol ---------------------------------------------------------------------------------
def test_getresponse_packet_layout() -> None:
    pkt = proto.getresponse_packet("#1P")
    assert pkt == bytes([0x40, 0xBF, 0, 0, 0, 0, 0, 3]) + b"#1P"
    h = proto.decode_header(pkt)
    assert (h.request_type, h.request, h.value, h.index, h.length) == (0x40, 0xBF, 0, 0, 3)


def test_other_packets_and_big_endian_length() -> None:
    assert proto.flush_packet() == bytes([0x40, 0xB3, 0, 0, 0, 0, 0, 0])
    assert proto.getbuffer_packet() == bytes([0xC0, 0xC5, 0, 0, 0, 0, 0x05, 0x78])  # 1400
    assert proto.readready_packet()[:2] == bytes([0xC0, 0xC2])
    pkt = proto.getresponse_packet("I" + "1" * 254)
    assert pkt[6:8] == (255).to_bytes(2, "big")


@pytest.mark.parametrize("bad", ["", "x" * 256, "#1P\r", "#1J=1\x06", "#1P\u00e9", "\x07"])
def test_unsendable_commands_are_refused(bad: str) -> None:
    with pytest.raises(PmacProtocolError):
        proto.getresponse_packet(bad)


def test_reply_parsing_lines_ack_and_errors() -> None:
    assert proto.parse_reply(b"\x06").lines == ()
    assert proto.parse_reply(b"12.5\r-3\r\x06").lines == ("12.5", "-3")
    assert proto.parse_reply(b"7\r\n8\r\n\x06").lines == ("7", "8")
    with pytest.raises(PmacCommandError) as err:
        proto.parse_reply(b"5\r\x07ERR003\r", "#1P#1Q")
    assert err.value.code == 3 and err.value.partial == ("5",)
    assert "data error or unrecognized command" in str(err.value) and "#1P#1Q" in str(err.value)
    with pytest.raises(PmacCommandError, match="ERR099.*unknown PMAC error"):
        proto.parse_reply(b"\x07ERR099\r")


@pytest.mark.parametrize("garbled", [b"12\r", b"1\x022\r\x06", b"\x07ERR003\rX", b"\xff\x06"])
def test_garbled_replies_raise_protocol_error(garbled: bytes) -> None:
    with pytest.raises(PmacProtocolError):
        proto.parse_reply(garbled)


def test_reply_complete() -> None:
    assert not proto.reply_complete(b"")
    assert not proto.reply_complete(b"12\r")
    assert not proto.reply_complete(b"\x07ERR0")
    assert proto.reply_complete(b"12\r\x06")
    assert proto.reply_complete(b"1\r\x07ERR003\r")


# -- status words -----------------------------------------------------------------------------
def test_status_decode_of_known_words() -> None:
    # activated, amp enabled, desired velocity zero | home complete, in position
    st = MotorStatus.from_hex("882000000401")
    assert st.activated and st.amp_enabled and st.desired_velocity_zero
    assert st.home_complete and st.in_position
    assert not (st.open_loop or st.neg_limit or st.pos_limit or st.amp_fault)
    st = MotorStatus.from_hex("C4000000000C")   # killed on -limit, amp fault + fatal FE
    assert st.neg_limit and st.open_loop and st.amp_fault and st.fatal_following_error
    assert not st.pos_limit and not st.amp_enabled
    assert st.faults == ["amp_fault", "fatal_following_error"]


def test_status_roundtrip_every_flag() -> None:
    names = [n for n in MotorStatus.__dataclass_fields__ if n not in ("word1", "word2")]
    for name in names:
        st = MotorStatus.from_flags(**{name: True})
        back = MotorStatus.from_hex(st.hex())
        assert [n for n in names if getattr(back, n)] == [name]


@pytest.mark.parametrize("bad", ["", "88200000040", "88200000040G", "8820000004011"])
def test_bad_status_words(bad: str) -> None:
    with pytest.raises(PmacProtocolError):
        MotorStatus.from_hex(bad)


# -- rail config and axis ---------------------------------------------------------------------
def test_config_from_description(config: RailConfig) -> None:
    rail = load_description(variant="rail_arm").rail
    assert (config.motor, config.counts_per_metre) == (rail.pmac_motor, rail.counts_per_metre)
    assert (config.lower, config.upper) == (rail.lower, rail.upper) == (-1.5, 1.5)
    assert config.to_counts(0.25) == 0.25 * rail.counts_per_metre
    assert config.to_metres(config.to_counts(-1.234)) == pytest.approx(-1.234)


@pytest.mark.parametrize("kw", [dict(motor=0), dict(motor=33), dict(counts_per_metre=0.0),
                                dict(lower=2.0), dict(max_velocity=0.0),
                                dict(counts_per_metre=math.nan)])
def test_config_validation(config: RailConfig, kw: dict) -> None:
    from dataclasses import asdict
    with pytest.raises(RailConfigError):
        RailConfig(**{**asdict(config), **kw})


@pytest.mark.parametrize("target", [1.5000001, -1.6, 3.0, math.nan, math.inf, -math.inf, "a"])
def test_out_of_range_jog_never_sent(config: RailConfig, target) -> None:
    port = RecordingPort()
    with pytest.raises(RailCommandError):
        RailAxis(port, config).jog_to(target)
    assert port.sent == []


def test_jog_formats_counts_within_limits(config: RailConfig) -> None:
    port = RecordingPort()
    ax = RailAxis(port, config)
    assert ax.jog_to(0.25)[0] == 50000.0
    assert ax.jog_to(1.5)[0] == 300000.0
    counts, before = ax.jog_to(-1.5)
    assert counts == -300000.0 and before.amp_enabled
    # the status is read on the card in the same line, just before the jog
    assert port.sent == ["#1?#1J=50000.0", "#1?#1J=300000.0", "#1?#1J=-300000.0"]


def test_configure_writes_ivariables(config: RailConfig) -> None:
    port = RecordingPort({"I10": ["3713991"]})
    RailAxis(port, config).configure()
    assert port.sent[:2] == ["I3=2 I6=1 I64=1", "I10"]   # communication set-up first
    sent = dict(kv.split("=") for kv in port.sent[2].split())
    # 0.5 m/s * 200000 counts/m = 100 counts/ms; 1 m/s^2 -> 0.2 counts/ms^2
    assert float(sent["I122"]) == pytest.approx(100.0)
    assert float(sent["I119"]) == pytest.approx(0.2)
    assert float(sent["I120"]) == 0 and float(sent["I121"]) == 0
    assert float(sent["I113"]) == 300000 and float(sent["I114"]) == -300000
    with pytest.raises(RailCommandError):
        RailAxis(port, config).configure(speed=0.6)


def test_configure_never_disables_a_soft_limit_nor_writes_exponents(config: RailConfig) -> None:
    from dataclasses import replace
    # a rail from 0 to 0.8 m, slow fine encoder: Ixx14=0 would switch the limit off,
    # Ixx19 = 2e-05 counts/ms^2 with %g would be written as an exponent
    rail = replace(config, lower=0.0, upper=0.8, counts_per_metre=1000.0,
                   max_acceleration=0.02)
    port = RecordingPort({"I10": ["3713991"]})
    RailAxis(port, rail).configure()
    assert "e" not in port.sent[2].lower()
    sent = dict(kv.split("=") for kv in port.sent[2].split())
    assert sent["I114"] == "-1" and sent["I113"] == "800"
    assert float(sent["I119"]) == pytest.approx(2e-05) and sent["I122"] == "0.5"
    mirrored = replace(config, lower=-0.5, upper=0.0, counts_per_metre=-1000.0)
    RailAxis(port, mirrored).configure()
    sent = dict(kv.split("=") for kv in port.sent[-1].split())
    assert sent["I113"] == "500" and sent["I114"] == "-1"
    with pytest.raises(RailCommandError, match="too small"):
        RailAxis(port, replace(config, max_acceleration=1e-12)).configure()


def test_read_scales_counts_and_servo_cycles(config: RailConfig) -> None:
    period = servo_period_from_i10(3713991)
    assert period == pytest.approx(0.4427e-3, rel=1e-4)
    port = RecordingPort({"#1P#1V#1F#1?": ["20000", f"{20000 * period:.6f}", "-40",
                                           "882000000401"]})
    st = RailAxis(port, config, servo_period=period).read()
    assert st.position == pytest.approx(0.1)
    assert st.velocity == pytest.approx(0.1, rel=1e-4)
    assert st.following_error == pytest.approx(-0.0002)
    assert st.status.home_complete
    port.replies["#1P#1V#1F#1?"] = ["1", "2", "3"]
    with pytest.raises(PmacProtocolError):
        RailAxis(port, config).read()


# -- emulator interpreter (no sockets) --------------------------------------------------------
def test_emulator_interpreter_replies() -> None:
    emu = PmacEmulator(motors=2, start_position=123)
    assert emu.execute("#1P") == b"123\r\x06"
    assert emu.execute("#2p #1v") == b"123\r0\r\x06"        # case and blanks ignored
    assert emu.execute("I122=12.5 I122 I222") == b"12.5\r32\r\x06"
    assert emu.execute("I10") == b"3713991\r\x06"
    assert emu.execute("#3?") == b"000000000000\r\x06"       # not an active motor
    assert emu.execute("I100..103").count(b"\r") == 4


@pytest.mark.parametrize("bad", ["#1Q", "#0P", "#33P", "#1J=abc", "I", "#1J*", "HELLO",
                                 "I9000", "#1J=1e3", "#1J=2E-5", "P1=1e3", "LIST", "&17",
                                 "OPEN PLC 32", "P1..", "M1->Z:$0"])
def test_emulator_err003(bad: str) -> None:
    assert PmacEmulator().execute(bad).endswith(b"\x07ERR003\r")


def test_emulator_error_stops_the_line() -> None:
    emu = PmacEmulator()
    assert emu.execute("#1P #1XX #1K") == b"0\r\x07ERR003\r"
    assert MotorStatus.from_hex(emu.execute("#1?")[:12].decode()).open_loop


# -- reply forms of a real card (Software Reference I3, I6, I64; Ethernet protocol) -----------
def test_stx_messages_are_split_out() -> None:
    msgs, rest = proto.split_messages(b"\x02PLC says hi\r12\r\x06")
    assert msgs == ["PLC says hi"] and rest == b"12\r\x06"
    msgs, rest = proto.split_messages(b"\x02half a mess")   # the CR is still on its way
    assert msgs == [] and rest == b"\x02half a mess" and not proto.reply_complete(rest)


@pytest.mark.parametrize("raw, complete", [(b"\x00", True), (b"\x07", True), (b"12\r", False),
                                           (b"\n12\r\n", True), (b"12\r\x06", True)])
def test_reply_complete_for_every_form(raw: bytes, complete: bool) -> None:
    assert proto.reply_complete(raw) is complete


def test_bell_without_number_and_lf_framing_are_explained() -> None:
    with pytest.raises(PmacCommandError, match="I6=0 or 2"):
        proto.parse_reply(b"\x07", "XYZ")
    with pytest.raises(PmacProtocolError, match="I3=1"):
        proto.parse_reply(b"\n12\r\n", "P1")
    assert proto.is_busy(b"\x00") and not proto.is_busy(b"\x06")


@pytest.mark.parametrize("x, text", [(2e-05, "0.00002"), (-0.0, "0"), (1e3, "1000"),
                                     (12.5, "12.5")])
def test_constants_are_written_without_exponent(x: float, text: str) -> None:
    assert proto.format_constant(x) == text


# -- emulator: variables, I-variable rules, commands (Turbo PMAC Software Reference) ---------
def test_emulator_variables_ranges_and_hex() -> None:
    emu = PmacEmulator()
    assert emu.execute("P1=5 P2=P1*2+1 Q3=$20000 P1..3") == b"5\r11\r0\r\x06"
    assert emu.execute("Q3 M7=-2.5 M7") == b"131072\r-2.5\r\x06"
    assert emu.execute("&2 Q3 &1 Q3") == b"0\r131072\r\x06"       # Q per coordinate system
    assert emu.execute("M1->Y:$0000C0,10 M1->") == b"Y:$0000C0,10\r\x06"
    assert emu.execute("I102 I9=0 I102 I9=2") == b"$78002\r491522\r\x06"   # I9 bit 1: hex
    assert emu.execute("I5=4 I5") == b"4\r\x06"


def test_emulator_i3_wraps_and_frames_replies() -> None:
    emu = PmacEmulator()
    # I3 has the range 0..3: 5 keeps its low bits (1); replies are then <LF>data<CR>, <LF>
    assert emu.execute("I3=5 I3") == b"\n1\r\n"
    assert emu.execute("I3=2 I6=0 XYZ") == b"\x07"               # I6=0: BELL, no number
    assert emu.execute("I6=1 I3=3 P1..2") == b"\n0\r\n0\r\x06"
    assert emu.execute("I3=2 XYZ") == b"\x07ERR003\r"


def test_emulator_identity_and_system_commands() -> None:
    emu = PmacEmulator()
    assert emu.execute("VER") == b"1.947\r\x06"                  # version only
    assert emu.execute("DATE CID TYPE") == b"01/07/2013\r603382\rTURBO2\r\x06"
    assert emu.execute("SAVE") == b"\x06"
    assert emu.execute("% &1 %50 %") == b"100\r50\r\x06"
    assert emu.execute("#2 #") == b"#2\r\x06"


def test_emulator_incremental_jogs() -> None:
    emu = PmacEmulator(start_position=100.0)
    emu.execute("I122=1000 I119=1000 #1J^50")         # relative to the actual position
    assert emu.motor(1).target == pytest.approx(150.0)
    emu.execute("#1J:-30")                              # relative to the commanded one
    assert emu.motor(1).target == pytest.approx(120.0)
    emu.execute("#1J=")                                 # back to the pre-jog position
    assert emu.motor(1).target == pytest.approx(150.0)


def test_emulator_plc_download_list_and_scan() -> None:
    emu = PmacEmulator()
    for line in ("OPEN PLC 3 CLEAR", "IF (P1 > 2 AND P2 = 0)", "P2 = P1 * 10", "ELSE",
                 "P3 = P3 + 1", "ENDIF", "CLOSE"):
        assert emu.execute(line) == b"\x06", line
    assert emu.execute("LIST PLC 3").count(b"\r") == 5
    prog = emu.plcs[3]
    prog.scan(emu, lambda cmd: None)
    assert emu.pvars.get(3) == 1.0 and 2 not in emu.pvars
    emu.execute("P1=4")
    prog.scan(emu, lambda cmd: None)
    assert emu.pvars[2] == 40.0


@pytest.mark.parametrize("bad", ["WHILE (P1 > 0)", "P1 = = 2", "IF P1 > 0", "SEND\"x\"",
                                 "P1 = 2E3", "GOTO 5"])
def test_emulator_refuses_plc_lines_outside_the_subset(bad: str) -> None:
    emu = PmacEmulator()
    emu.execute("OPEN PLC 4 CLEAR")
    assert emu.execute(bad) == b"\x07ERR003\r"
    assert emu.execute("IF (P1 = 0)") == b"\x06"
    assert emu.execute("CLOSE") == b"\x07ERR009\r"       # IF without ENDIF


def test_watchdog_program_uses_only_the_emulated_subset(config: RailConfig) -> None:
    from hyperarm_driver.pmac.watchdog import WatchdogConfig, download_lines
    emu = PmacEmulator()
    period = servo_period_from_i10(3713991)
    cfg = WatchdogConfig(timeout=0.1)
    assert cfg.cycles(period) == 226                   # 100 ms / 0.4427 ms, rounded up
    for line in download_lines(cfg, 1, period):
        assert emu.execute(line) == b"\x06", line
    assert emu.plcs[10].enabled and len(emu.plcs[10].lines) > 5
    with pytest.raises(RailConfigError):
        WatchdogConfig(heartbeat=8001, seen=8001)


def test_emulator_status_m_variables_match_the_status_word() -> None:
    # M-variables on the motor status words (Turbo PMAC suggested definitions) read the bits
    # that #n? reports, for motor 2 too ($80 further)
    emu = PmacEmulator(motors=2)
    bits = [("X", 19), ("X", 18), ("X", 13), ("Y", 2), ("Y", 3), ("Y", 10), ("Y", 0)]
    for motor in (1, 2):
        base = (motor - 1) * 0x80
        for k, (space, bit) in enumerate(bits):
            addr = (0xB0 if space == "X" else 0xC0) + base
            emu.execute(f"M{10 + k}->{space}:${addr:06X},{bit},1")
        for setup in ("", "#{m}J/", "#{m}HMZ", "#{m}K"):
            emu.execute(setup.format(m=motor))
            st = MotorStatus.from_hex(emu.execute(f"#{motor}?")[:12].decode())
            got = emu.execute(f"M10..{10 + len(bits) - 1}").split(b"\r")[:-1]
            want = [(st.word1 if s == "X" else st.word2) >> b & 1 for s, b in bits]
            assert [int(g) for g in got] == want, (motor, setup)
        emu.execute(f"#{motor}J/")
        emu.set_amp_fault(motor, True)                    # kills the enabled motor
        assert emu.execute("M14 M10") == b"1\r0\r\x06"   # amplifier fault, not enabled
        emu.set_amp_fault(motor, False)


class EmulatorPort:
    """A RailAxis port on the emulator's interpreter (no sockets), as one host connection."""

    def __init__(self, emu: PmacEmulator) -> None:
        from hyperarm_driver.pmac.emulator import _Port
        self.emu, self.port = emu, _Port()

    def command(self, command: str) -> list[str]:
        return list(proto.parse_reply(self.emu.execute(command, self.port), command).lines)


@pytest.mark.parametrize("seed", range(6))
def test_watchdog_never_re_enables_a_motor_killed_by_anyone(config: RailConfig,
                                                            seed: int) -> None:
    """The safety PLC's trip is ``#nJ/``, which closes a killed motor's loop. A motor killed
    by the driver (``rail/set_torque false``), by another host's ``#1K`` or by the card on a
    fault (fatal following error, amplifier fault) while the host still feeds the heartbeat
    or after it stopped, moving or at rest, never gets its loop closed again when the
    heartbeat stops; a motor nobody killed is stopped and held (the trip itself). Random
    instants, every kind once per seed, 6 seeds. (Before the open-loop check, another host's kill
    was undone by the trip: closed_loop True, one more enable.)"""
    import random
    import time as _time

    from hyperarm_driver.pmac.watchdog import WatchdogConfig
    rng = random.Random(seed)
    timeout = 0.03
    kinds = rng.sample(["driver", "other host", "fatal following error", "amplifier fault",
                        "nobody"], 5)
    for trial, kind in enumerate(kinds):
        emu = PmacEmulator(start_position=2000)
        ax = RailAxis(EmulatorPort(emu), config, watchdog=WatchdogConfig(timeout=timeout))
        other = EmulatorPort(emu)                     # another host on the same card
        ax.configure()
        ax.enable()
        emu.motor(1).homed = True
        if rng.random() < 0.7:                        # moving at the kill
            ax.jog_to(rng.uniform(0.05, 0.3))
        feed_until = _time.monotonic() + rng.uniform(0.0, 0.02)
        while _time.monotonic() < feed_until:         # the host's polls feed the heartbeat
            ax.read()
        if rng.random() < 0.5:                        # the heartbeat stops before the kill
            _time.sleep(rng.uniform(0.0, 2 * timeout))
        enables = emu.motor(1).enables
        if kind == "driver":
            ax.kill()
        elif kind == "other host":
            other.command("#1K")
        elif kind == "fatal following error":
            emu.set_disturbance(1, 2500)
            emu.set_disturbance(1, 0)
        elif kind == "amplifier fault":
            emu.set_amp_fault(1, True)
            emu.set_amp_fault(1, False)
        _time.sleep(3 * timeout)                      # heartbeat gone: the timer runs out
        m = emu.motor(1)
        what = f"seed {seed} trial {trial}: {kind}"
        if kind == "nobody":
            assert m.closed_loop and emu.pvars[8003] == 0, what     # tripped: held
        else:
            assert not m.closed_loop, what + ": the watchdog closed the loop again"
            assert m.enables == enables, what
            assert emu.pvars[8003] == 0, what


def test_emulator_status_queries_have_the_cards_lengths() -> None:
    """Issue 24 item 9: ``??`` is the addressed coordinate system's status (three 24-bit
    words, 18 hex digits) and ``???`` the global status (two words, 12 digits), one line
    each (Turbo PMAC Software Reference); the emulator answered two and three copies of the
    motor's 12-digit status. ``#n?`` stays the motor's status, also beside the others."""
    import re
    emu = PmacEmulator(motors=2)
    hex_line = re.compile(rb"[0-9A-F]+")

    def lines(cmd: str) -> list[bytes]:
        reply = emu.execute(cmd)
        assert reply.endswith(b"\x06"), (cmd, reply)
        return reply[:-1].split(b"\r")[:-1]

    for cmd, widths in (("??", [18]), ("???", [12]), ("#1?", [12]), ("&1??", [18]),
                        ("&16??", [18]), ("#2??", [18]), ("#1?#2?", [12, 12]),
                        ("???#1?", [12, 12]), ("#1P??", [None, 18]),
                        ("?? #2?", [18, 12])):
        got = lines(cmd)
        assert len(got) == len(widths), (cmd, got)
        for x, w in zip(got, widths):
            assert w is None or (len(x) == w and hex_line.fullmatch(x)), (cmd, got)
    emu.execute("#1J/")                                 # motor 1 enabled: its word changes,
    motor = lines("#1?")[0]                             # not the CS or global status
    assert MotorStatus.from_hex(motor.decode()).amp_enabled
    assert lines("??") == [b"0" * 18] and lines("???") == [b"0" * 12]
    assert emu.execute("&17??").endswith(b"ERR003\r")


def test_mock_rail_diagnostics_carry_the_pmac_drivers_keys() -> None:
    """The mock's rail status mirrors the PMAC driver's /diagnostics keys (a client reads
    either the same way), the watchdog trip count and the last refusal included."""
    from hyperarm_driver.mock.diagnostics import BusStats, mock_diagnostics
    from hyperarm_driver.mock.joint_sim import JointSim
    from hyperarm_driver.pmac.axis import RailState
    from hyperarm_driver.pmac.driver import DriverSnapshot

    sim = JointSim(load_description(variant="rail_arm"))
    stats = BusStats(rejected_setpoints=1, last_rejection="rail not homed")
    (rail,) = [s for s in mock_diagnostics(sim, stats, 1.0, 1.0) if s.name.endswith(": rail")]
    snap = DriverSnapshot(True, RailState(0.0, 0.0, 0.0, MotorStatus.from_words(0, 0)), 0.0,
                          0.001, 0, 0, "", "127.0.0.1:1025", 1)
    assert set(rail.values) == {k for k, _ in snap.diagnostic()[2]}
    assert rail.values["last_rejection"] == "rail not homed"
    assert rail.values["watchdog_trips"] == "0"
