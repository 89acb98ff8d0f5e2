"""e2e tier: the installed ``dxl_emulator`` executable as the official dynamixel-sdk sees it:
the Protocol 2.0 inter-byte gap and Control Table Backup (issue 24 item 9). The SDK talks
to the emulator's pty like a host program to a U2D2."""
from __future__ import annotations

import time

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from hyperarm_driver.dynamixel import protocol2 as p2
from hyperarm_driver.dynamixel.emulator import EmulatorControl

pytestmark = pytest.mark.e2e

ph = PacketHandler(2.0)
SID = 5


def _connect(path: str) -> EmulatorControl | None:
    try:
        return EmulatorControl(path)
    except (FileNotFoundError, ConnectionRefusedError):   # not bound / not listening yet
        return None


@pytest.fixture
def bus(launch, tmp_path, wait_for):
    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    launch("hyperarm_driver", "dxl_emulator", "--servos", f"{SID}:XM430-W350", "--link", link,
           "--control", ctl)
    control = wait_for(lambda: _connect(ctl), 20.0, what="emulator control socket")
    port = PortHandler(link)
    assert port.openPort() and port.setBaudRate(1_000_000)
    yield port, control
    port.closePort()
    control.close()


def _status(port, packet: bytes, timeout_ms: float = 250.0) -> tuple[list[int], int]:
    """Send raw bytes and read one status packet (a loaded host schedules the emulator
    late: the wait is longer than the SDK's, a missing reply is still missing)."""
    port.clearPort()
    port.writePort(list(packet))
    port.setPacketTimeoutMillis(timeout_ms)
    return ph.rxPacket(port, False)


def test_installed_emulator_drops_a_packet_whose_bytes_pause(bus) -> None:
    """A ping split 7 + 3 bytes, 20 ms apart (the issue's example), is not answered; the
    same ping whole is. The pause starts once the emulator has taken the first 7 bytes; a
    try whose pause the emulator could not see (its process not scheduled through it: it
    then saw the 10 bytes at once, stats ``last_gap_s``) is repeated, up to 8 tries."""
    port, control = bus
    ping = p2.build_packet(SID, p2.INST_PING)
    seen = 0
    for _ in range(8):
        stats = control("stats")
        port.clearPort()
        port.writePort(list(ping[:7]))
        deadline = time.monotonic() + 5.0
        while control("stats")["bytes_in"] < stats["bytes_in"] + 7:
            assert time.monotonic() < deadline, "the emulator did not take the first bytes"
            time.sleep(0.001)
        time.sleep(0.02)
        port.writePort(list(ping[7:]))
        port.setPacketTimeoutMillis(100)
        _, result = ph.rxPacket(port, False)
        after = control("stats")
        if after["last_gap_s"] > p2.BYTE_GAP_TIMEOUT:
            assert result != COMM_SUCCESS, "a ping whose bytes paused 20 ms was answered"
            assert after["frame_timeouts"] == stats["frame_timeouts"] + 1
            seen += 1
        rx, result = _status(port, ping)
        assert result == COMM_SUCCESS and rx[4] == SID
        if seen >= 3:
            break
    assert seen >= 1, "the emulator never saw the pause"


def test_installed_emulator_control_table_backup(bus) -> None:
    """Control Table Backup (0x20) as the e-Manual gives it: the store packet of its example
    (``FF FF FD 00 01 08 00 20 01 43 54 52 4C``, CRC ``16 F5`` for ID 1; here ID 5) is
    answered without error by the emulated XM430-W350 (firmware 46), Backup Ready reads 1,
    and a restore brings an EEPROM value back (the servo reboots itself)."""
    port, control = bus
    example = p2.build_packet(1, p2.INST_CONTROL_TABLE_BACKUP, b"\x01CTRL")
    assert example[-2:] == bytes([0x16, 0xF5])               # the e-Manual's CRC
    assert ph.read1ByteTxRx(port, SID, 6)[0] == 46           # Firmware Version
    rx, result = _status(port, p2.build_packet(SID, p2.INST_CONTROL_TABLE_BACKUP, b"\x01CTRL"))
    assert result == COMM_SUCCESS and rx[8] == 0, rx
    assert ph.read1ByteTxRx(port, SID, 147)[:2] == (1, COMM_SUCCESS)   # Backup Ready
    assert ph.write1ByteTxRx(port, SID, 9, 10) == (COMM_SUCCESS, 0)   # Return Delay 250 -> 10
    rx, result = _status(port, p2.build_packet(SID, p2.INST_CONTROL_TABLE_BACKUP, b"\x02CTRL"))
    assert result == COMM_SUCCESS and rx[8] == 0, rx
    deadline = time.monotonic() + 3.0
    while ph.ping(port, SID)[1] != COMM_SUCCESS:             # silent while it reboots
        assert time.monotonic() < deadline, "no answer after the restore"
    # the value only with its result: a read lost under load (a make test run: 252, its
    # result unchecked) is read again within the deadline, never judged
    while True:
        value, result, _err = ph.read1ByteTxRx(port, SID, 9)
        if result == COMM_SUCCESS or time.monotonic() > deadline:
            break
    assert (value, result) == (250, COMM_SUCCESS), (value, ph.getTxRxResult(result))
