"""Exceptions of the PMAC package: one root, precise subclasses.

``PmacError`` is the root. Link problems (``PmacLinkError``) mean the TCP/serial link is not
usable and the caller should stop commanding and reconnect; ``PmacCommandError`` carries an
``ERRnnn`` reply of the card with its text; ``RailCommandError`` is a command refused on the
host side before anything was sent (out of soft limits, not homed, ...).
"""
from __future__ import annotations

__all__ = [
    "PmacError", "PmacProtocolError", "PmacLinkError", "PmacTimeoutError",
    "PmacCommandError", "PmacBusyError", "PMAC_ERROR_TEXTS", "RailError", "RailConfigError",
    "RailCommandError",
]

# Turbo PMAC on-line command error codes (reported as <BELL>ERRnnn<CR> with I6=1 or 3).
PMAC_ERROR_TEXTS: dict[int, str] = {
    0: "error reported without a number (the card is set to I6=0 or 2; set I6=1)",
    1: "command not allowed during program execution",
    2: "password error",
    3: "data error or unrecognized command",
    4: "illegal character: bad value (>127 ASCII) or serial parity/framing error",
    5: "command not allowed unless buffer is open",
    6: "no room in buffer for command",
    7: "buffer already in use",
    8: "MACRO auxiliary communications error",
    9: "program structural error (e.g. ENDIF without IF)",
    10: "both overtravel limits set for a motor in the coordinate system",
    11: "previous move not completed",
    12: "a motor in the coordinate system is open-loop",
    13: "a motor in the coordinate system is not activated",
    14: "no motors in the coordinate system",
    15: "not pointing to valid program buffer",
    16: "running improperly structured program (e.g. missing ENDWHILE)",
    17: "trying to resume after H or Q with motors out of stopped position",
    18: "attempt to perform phase reference during move, move during phase reference, "
        "or enabling with phase clock error",
    19: "illegal position-change command while moves stored in CCBUFFER",
}


class PmacError(Exception):
    """Root of every error raised by the PMAC package."""


class PmacProtocolError(PmacError):
    """A packet or reply does not follow the Turbo PMAC Ethernet protocol."""


class PmacLinkError(PmacError):
    """The link to the card is down (refused, closed, reset); reconnect before commanding."""


class PmacTimeoutError(PmacLinkError):
    """The card did not answer within the timeout (the link is then treated as lost)."""


class PmacBusyError(PmacTimeoutError):
    """The card answered NUL (busy, command not taken) until the reply timeout ran out."""


class PmacCommandError(PmacError):
    """The card rejected a command with ``ERRnnn``.

    ``code`` is nnn, ``text`` the PMAC manual's description, ``command`` what was sent and
    ``partial`` the reply lines the card produced before the error (multi-command lines).
    """

    def __init__(self, code: int, command: str = "", partial: tuple[str, ...] = ()) -> None:
        self.code = int(code)
        self.text = PMAC_ERROR_TEXTS.get(self.code, "unknown PMAC error")
        self.command = command
        self.partial = tuple(partial)
        where = f" in reply to {command!r}" if command else ""
        super().__init__(f"PMAC ERR{self.code:03d}{where}: {self.text}")


class RailError(PmacError):
    """Root of the rail-axis errors (host side)."""


class RailConfigError(RailError, ValueError):
    """Invalid rail axis configuration (motor number, scaling, limits, ...)."""


class RailCommandError(RailError, ValueError):
    """A rail command was refused on the host side; nothing was sent to the card."""
