"""pmac_emulator against a public Turbo PMAC client this project did not write: dls-pmaclib
(Diamond Light Source, PyPI), over its Ethernet interface (VR_PMAC_GETRESPONSE/GETBUFFER).

dls-pmaclib 3.1.2 connects with ``i6=1 i3=2 ver`` and accepts only a bare version
(``^\\d+\\.\\d+\\s*\\r\\x06$``), identifies the card with ``cid``, reads variables with
``getIVars`` (it has no ``getVar``: reads go through ``sendCommand`` / ``getIVars``) and
writes them with ``setVar``. The emulator's replies are what a Turbo PMAC sends (Turbo PMAC
Software Reference: VERSION, DATE, CID, I9, I20..I23, J^, J=, J/, HM).
"""
from __future__ import annotations

import pytest

from hyperarm_driver.pmac.emulator import CID, DATE, VERSION, PmacEmulator

pytestmark = pytest.mark.emulator

import dls_pmaclib.dls_pmacremote as remote  # noqa: E402 (a pinned test dependency)


@pytest.fixture
def emu():
    with PmacEmulator(motors=2, start_position=1000) as e:
        e.execute("I3=1 I6=0")       # factory framing: dls-pmaclib must set I3/I6 itself
        yield e


@pytest.fixture
def pmac(emu):
    p = remote.PmacEthernetInterface(verbose=False, timeout=2.0)
    p.setConnectionParams("127.0.0.1", emu.port)
    assert p.connect() is None       # None = connected and "ver" understood
    yield p
    p.disconnect()


def test_connect_sets_i3_i6_and_reads_the_version(pmac, emu) -> None:
    assert (emu.globals[3], emu.globals[6]) == (2.0, 1.0)
    assert pmac.sendCommand("ver") == (f"{VERSION}\r\x06", True)
    assert pmac.sendCommand("date") == (f"{DATE}\r\x06", True)
    assert pmac.getPmacModelCode() == CID
    assert pmac.getPmacModel() == "Geo Brick (3U Turbo PMAC2)"
    assert pmac.getNumberOfAxes() == 8          # no MACRO ICs: I20..I23 answer $0


def test_send_command_and_errors(pmac) -> None:
    assert pmac.sendCommand("#1P #2P") == ("1000\r1000\r\x06", True)
    assert pmac.sendCommand("#1XYZ") == ("\x07ERR003\r", True)    # passed up, link fine
    assert pmac.sendCommand("#1J=1e3") == ("\x07ERR003\r", True)  # no exponent on the card
    # (long replies: dls-pmaclib 3.1.2 refuses a 1400-byte first piece that happens to end
    # with CR; GETBUFFER is covered by test_pmac_emulator.py with this project's client)


def test_get_and_set_variables(pmac, emu) -> None:
    pmac.setVar("P100", 42.5)
    pmac.setVar("Q7", "$20")
    pmac.setVar("I122", 12)
    assert pmac.sendCommand("P100 Q7") == ("42.5\r32\r\x06", True)
    assert pmac.getIVars(100, [22, 19, 2]) == ["12", "0.015625", "$78002"]
    assert pmac.getAxisSetupIVars(2, [22]) == ["32"]
    assert emu.pvars[100] == 42.5 and emu.motor(1).ivars[22] == 12


def test_motion_helpers(pmac, emu) -> None:
    assert pmac.jogInc(1, "pos", 200)[2] is True         # #1J^200, relative to actual
    assert emu.motor(1).target == pytest.approx(1200)
    pmac.jogTo(2, -500)
    assert emu.motor(2).target == pytest.approx(-500)
    pmac.jogStop(2)
    assert emu.motor(2).closed_loop
    results = list(pmac.sendSeries([(1, "P1=1"), (2, "P2=P1+1"), (3, "BAD")]))
    assert [ok for ok, *_ in results] == [True, True, False]
    assert emu.pvars[2] == 2
