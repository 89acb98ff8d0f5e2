"""The on-card safety PLC the rail driver downloads at configure: host watchdog and fault latch.

The Turbo PMAC finishes a jog on its own if the host goes away, and every jog command closes
the loop of a killed motor (PMAC Software Reference, O{constant}: "Closed-loop control for
the motor can be re-established with the J command"), clearing its fault flags ("changes
from 1 to 0 when the offending motor is re-enabled", Turbo PMAC Software Reference,
coordinate-system status). So the card itself must

1. stop the rail when the host is gone: the driver increments a heartbeat P-variable in
   every poll; the PLC re-arms a countdown timer (Isx11: "Isx11 will count down one unit per
   servo cycle", Software Reference; "multiply [ms] by 8,388,608 and divide by I10")
   whenever the heartbeat changes, and when the timer runs out while the host has torque on
   and the loop is closed (the "armed" P-variable is 2, see 3.) it disarms and issues
   ``#nJ/`` (decelerate at the jog acceleration and hold, servo on);
2. keep a motor the card killed killed: when the fatal-following-error or amplifier-fault
   status bit of the motor is set (read through M-variables on the motor status words, the
   Turbo PMAC suggested definitions ``M142->Y:$0000C0,2,1``, ``M143->Y:$0000C0,3,1`` for
   motor 1, $80 further per motor) it
   disarms and deactivates the motor (Ixx00=0), so that no jog streamed afterwards can close
   its loop; ``set_torque true`` re-activates it (Ixx00=1) and closes the loop (``J/``);
3. never re-enable a motor that anyone killed: ``J/`` closes a killed motor's loop, so the
   watchdog may only send it to a motor whose loop is closed. The armed flag has two armed
   values: the enable sets 1 (in the same line as its ``J/``); the PLC raises it to 2 once it
   reads the loop closed (the Open Loop Mode bit of the first ``#n?`` word, X:$0000B0 bit 18
   for motor 1: "1 when the servo loop for the motor is open, either with outputs enabled
   or disabled (killed) ... 0 when the servo loop is closed", Turbo PMAC Software
   Reference, ``#n?``; an open-loop ``O`` command counts too) and drops it
   to 0 as soon as it reads the loop open again, whoever opened it (the driver's ``K``,
   another host's ``K``, the card's own kill on a fault). The trip fires only at 2, and
   only in the scan that has just read the loop closed; the disarm at 1 (timer out before
   the loop was seen closed) sends nothing.

The program uses only P-variables, the timer, M-variable reads, IF/ENDIF and CMD, which is
the subset the emulator interprets (:mod:`.plc`), so a wrong program fails the tests.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import RailConfigError

__all__ = ["WatchdogConfig", "program", "download_lines"]


@dataclass(frozen=True)
class WatchdogConfig:
    """Numbers of the PLC and variables the safety PLC uses (change them if the card's own
    programs use these), and the heartbeat timeout ``timeout`` (s)."""

    plc: int = 10
    heartbeat: int = 8001        # P: incremented by the driver in every poll
    seen: int = 8002             # P: the heartbeat value the PLC saw last
    armed: int = 8003            # P: 1 enabled by the host, 2 and the loop seen closed;
                                 # 0 = off, tripped or killed
    mvar: int = 8140             # M: first of the three status-bit M-variables (+0..+2)
    coordinate_system: int = 1   # its Isx11 is the countdown timer
    timeout: float = 0.1

    def __post_init__(self) -> None:
        if not 1 <= self.plc <= 31:
            raise RailConfigError(f"watchdog PLC must be 1..31, got {self.plc}")
        vars_ = (self.heartbeat, self.seen, self.armed)
        if len(set(vars_)) != 3 or not all(0 <= v <= 8191 for v in vars_):
            raise RailConfigError(f"watchdog P-variables must be distinct 0..8191: {vars_}")
        if not 0 <= self.mvar <= 8189:
            raise RailConfigError(f"watchdog M-variables must start at 0..8189, got {self.mvar}")
        if not 1 <= self.coordinate_system <= 16:
            raise RailConfigError("watchdog coordinate system must be 1..16")
        if not 0.005 <= self.timeout <= 10.0:
            raise RailConfigError(f"watchdog timeout must be 0.005..10 s, got {self.timeout}")

    @property
    def timer(self) -> str:
        return f"I{5000 + self.coordinate_system * 100 + 11}"

    def cycles(self, servo_period: float) -> int:
        """The timeout in servo cycles (rounded up)."""
        return max(1, math.ceil(self.timeout / servo_period - 1e-9))


def program(cfg: WatchdogConfig, motor: int, servo_period: float) -> list[str]:
    """The PLC program lines (between OPEN PLC and CLOSE)."""
    hb, seen, armed, t = f"P{cfg.heartbeat}", f"P{cfg.seen}", f"P{cfg.armed}", cfg.timer
    ffe, amp, opened = f"M{cfg.mvar}", f"M{cfg.mvar + 1}", f"M{cfg.mvar + 2}"
    act = f"I{motor * 100}"
    return [
        f"IF ({hb} != {seen})",
        f"{seen} = {hb}",
        f"{t} = {cfg.cycles(servo_period)}",
        "ENDIF",
        f"IF ({ffe} = 1 OR {amp} = 1)",
        f"IF ({act} = 1)",
        f"{armed} = 0",
        f"{act} = 0",
        "ENDIF",
        "ENDIF",
        f"IF ({armed} = 1 AND {opened} = 0)",
        f"{armed} = 2",
        "ENDIF",
        f"IF ({armed} = 2 AND {opened} = 1)",
        f"{armed} = 0",
        "ENDIF",
        f"IF ({t} < 1 AND {armed} = 1)",
        f"{armed} = 0",
        "ENDIF",
        f"IF ({t} < 1 AND {armed} = 2)",
        f"{armed} = 0",
        f'CMD"#{motor}J/"',
        "ENDIF",
    ]


def download_lines(cfg: WatchdogConfig, motor: int, servo_period: float) -> list[str]:
    """Every command line of the download, in order: disable and disarm, M-variable
    definitions, the program, CLOSE, ENABLE."""
    status = 0x0000C0 + (motor - 1) * 0x80       # motor status word 2 (Y register)
    word1 = 0x0000B0 + (motor - 1) * 0x80        # motor status word 1 (X register)
    return [f"DISABLE PLC {cfg.plc}",
            f"P{cfg.armed}=0 P{cfg.seen}=P{cfg.heartbeat}",
            f"M{cfg.mvar}->Y:${status:06X},2,1 M{cfg.mvar + 1}->Y:${status:06X},3,1 "
            f"M{cfg.mvar + 2}->X:${word1:06X},18,1",
            f"OPEN PLC {cfg.plc} CLEAR",
            *program(cfg, motor, servo_period),
            "CLOSE",
            f"{cfg.timer}={cfg.cycles(servo_period)}",
            f"ENABLE PLC {cfg.plc}"]
