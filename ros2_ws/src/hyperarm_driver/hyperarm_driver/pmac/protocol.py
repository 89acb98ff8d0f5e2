"""The Turbo PMAC Ethernet protocol (TCP port 1025), as plain bytes in and out.

Every request is an 8-byte header followed by ``wLength`` data bytes::

    RequestType (u8)  0x40 = VR_DOWNLOAD (host to card), 0xC0 = VR_UPLOAD (card to host)
    Request     (u8)  VR_PMAC_GETRESPONSE 0xBF, VR_PMAC_FLUSH 0xB3, VR_PMAC_GETBUFFER 0xC5, ...
    wValue      (u16, big-endian)
    wIndex      (u16, big-endian)
    wLength     (u16, big-endian)  number of data bytes that follow
    bData       ASCII command text (no terminator)

A ``GETRESPONSE`` reply is at most 1400 bytes of ASCII. With I3=2 (Turbo PMAC Software
Reference, I3) it is zero or more response lines each ended by CR (0x0D), the whole reply
ended by ACK (0x06); I3=3 also puts LF before each line. If the card reports an error
(I6=1 or 3, Software Reference I6) the reply ends instead with BELL (0x07) ``ERRnnn`` CR;
lines produced before the error precede it; with I6=0 or 2 the BELL comes alone. Other
forms a real card sends, all accepted here:

- ``<STX>text<CR>``: a line the card sends on its own (a PLC's SEND/CMD output) while I64=1
  (Software Reference, I64: "preceded by a <CONTROL-B> (start-transmission) character");
  the Ethernet firmware returns only up to that CR and keeps the rest for GETBUFFER
  (User Manual, VR_PMAC_GETBUFFER: "If a <BEL> or <STX> character is detected, only the
  data up to the next <CR> is returned"). :func:`split_messages` takes such lines out.
- a lone NUL (0x00): the card is busy and did not take the command (public drivers such as
  dls-pmaclib read it as "PMAC busy"; SAVE answers it while writing flash).
- an LF-terminated reply: the card is set to I3=1; refused with a clear message.

A longer reply is fetched in further 1400-byte pieces with ``GETBUFFER``. ``FLUSH`` sends
the card a <CTRL-X>; "one byte is returned upon successful completion" (UMAC Turbo CPU
manual, Ethernet protocol, VR_PMAC_FLUSH): the <CTRL-X> echo (0x18) with I63=1, otherwise
another byte (``@`` has been seen); any single byte is accepted as the acknowledgement.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import IntEnum

from .errors import PmacCommandError, PmacProtocolError

__all__ = [
    "VR_DOWNLOAD", "VR_UPLOAD", "Request", "HEADER", "HEADER_SIZE", "MAX_DATA",
    "REPLY_CHUNK", "MAX_COMMAND", "ACK", "BELL", "CR", "LF", "FLUSH_REPLY", "Header",
    "encode_request", "decode_header", "getresponse_packet", "flush_packet",
    "getbuffer_packet", "readready_packet", "check_command", "reply_complete",
    "parse_reply", "Reply", "parse_number", "STX", "NUL", "split_messages", "is_busy",
    "format_constant",
]

VR_DOWNLOAD = 0x40
VR_UPLOAD = 0xC0


class Request(IntEnum):
    """Request codes (bRequest) of the Turbo PMAC Ethernet protocol."""

    SENDLINE = 0xB0
    GETLINE = 0xB1
    FLUSH = 0xB3
    GETMEM = 0xB4
    SETMEM = 0xB5
    SETBIT = 0xBA
    SETBITS = 0xBB
    PORT = 0xBE
    GETRESPONSE = 0xBF
    READREADY = 0xC2
    CTRL_RESPONSE = 0xC4
    GETBUFFER = 0xC5
    WRITEBUFFER = 0xC6
    WRITEERROR = 0xC7
    FWDOWNLOAD = 0xCB
    IPADDRESS = 0xE0


HEADER = struct.Struct(">BBHHH")
HEADER_SIZE = HEADER.size          # 8
MAX_DATA = 1492                    # bData size of the card's ETHERNETCMD
REPLY_CHUNK = 1400                 # largest reply packet of the card
MAX_COMMAND = 255                  # the card's on-line command line is 256 chars with CR
ACK = 0x06
BELL = 0x07
CR = 0x0D
LF = 0x0A
FLUSH_REPLY = b"@"
STX = 0x02
NUL = 0x00

_ERR = re.compile(rb"\x07ERR(\d{3})\r")


@dataclass(frozen=True)
class Header:
    """A decoded 8-byte request header."""

    request_type: int
    request: int
    value: int
    index: int
    length: int


def encode_request(request_type: int, request: int, data: bytes = b"", value: int = 0,
                   index: int = 0, length: int | None = None) -> bytes:
    """Header + data. ``length`` defaults to ``len(data)`` (GETBUFFER sends none but asks 1400)."""
    if request_type not in (VR_DOWNLOAD, VR_UPLOAD):
        raise PmacProtocolError(f"request type must be 0x40 or 0xC0, got {request_type:#x}")
    if len(data) > MAX_DATA:
        raise PmacProtocolError(f"{len(data)} data bytes exceed the packet's {MAX_DATA}")
    n = len(data) if length is None else length
    for label, v in (("request", request), ("value", value), ("index", index), ("length", n)):
        if not 0 <= v <= (0xFF if label == "request" else 0xFFFF):
            raise PmacProtocolError(f"{label} {v} out of range")
    return HEADER.pack(request_type, request, value, index, n) + data


def decode_header(raw: bytes) -> Header:
    """Decode the first 8 bytes of a request."""
    if len(raw) < HEADER_SIZE:
        raise PmacProtocolError(f"short header: {len(raw)} bytes")
    return Header(*HEADER.unpack_from(raw))


def check_command(command: str) -> bytes:
    """The ASCII bytes of an on-line command; raises PmacProtocolError if it cannot be sent.

    Printable 7-bit ASCII only (no control characters: the card would take CR as end of
    line and a control character as a control command), 1..255 characters.
    """
    if not isinstance(command, str):
        raise PmacProtocolError(f"command must be str, got {type(command).__name__}")
    if not command or len(command) > MAX_COMMAND:
        raise PmacProtocolError(f"command length {len(command)} not within 1..{MAX_COMMAND}")
    bad = [c for c in command if not 0x20 <= ord(c) < 0x7F]
    if bad:
        raise PmacProtocolError(f"command {command!r} has non-printable/non-ASCII {bad!r}")
    return command.encode("ascii")


def getresponse_packet(command: str) -> bytes:
    """VR_PMAC_GETRESPONSE: send one on-line command line, get its response."""
    return encode_request(VR_DOWNLOAD, Request.GETRESPONSE, check_command(command))


def flush_packet() -> bytes:
    """VR_PMAC_FLUSH: discard the card's pending output (answer: ``@``)."""
    return encode_request(VR_DOWNLOAD, Request.FLUSH)


def getbuffer_packet() -> bytes:
    """VR_PMAC_GETBUFFER: fetch the next piece (up to 1400 bytes) of a long reply."""
    return encode_request(VR_UPLOAD, Request.GETBUFFER, length=REPLY_CHUNK)


def readready_packet() -> bytes:
    """VR_PMAC_READREADY: 2-byte answer, first byte 1 if the card has output pending."""
    return encode_request(VR_UPLOAD, Request.READREADY, length=2)


def split_messages(buf: bytes | bytearray) -> tuple[list[str], bytes]:
    """(the ``<STX>text<CR>`` lines at line starts in ``buf``, the rest of ``buf``).

    An STX line not yet ended by CR stays in the rest (more bytes are on their way).
    """
    data, msgs, out, i = bytes(buf), [], bytearray(), 0
    while i < len(data):
        if data[i] == STX and (i == 0 or data[i - 1] in (CR, LF)):
            end = data.find(b"\r", i)
            if end < 0:
                out += data[i:]
                break
            msgs.append(data[i + 1:end].decode("ascii", errors="replace"))
            i = end + 1
            continue
        out.append(data[i])
        i += 1
    return msgs, bytes(out)


def is_busy(buf: bytes | bytearray) -> bool:
    """A NUL reply: the card was busy and did not take the command."""
    return bool(buf) and all(b == NUL for b in buf)


def reply_complete(buf: bytes | bytearray) -> bool:
    """True once ``buf`` (without STX lines) holds a whole reply: ends with ACK, has BELL
    ERRnnn CR, is a lone BELL (I6=0/2), is NUL (busy), or ends with LF (I3=1 framing)."""
    if not buf:
        return False
    if buf[-1] in (ACK, BELL) or is_busy(buf):
        return True
    if buf[-1] == LF:
        return bytes(buf) == b"\n" or bytes(buf).endswith(b"\r\n")
    return buf[-1] == CR and BELL in buf and _ERR.search(bytes(buf)) is not None


@dataclass(frozen=True)
class Reply:
    """The response lines of one command line (CR/LF stripped, empty lines dropped)."""

    lines: tuple[str, ...]


def _lines(raw: bytes) -> tuple[str, ...]:
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise PmacProtocolError(f"non-ASCII bytes in reply: {raw[:40]!r}") from exc
    return tuple(s.strip("\n") for s in text.split("\r") if s.strip("\n"))


def parse_reply(buf: bytes, command: str = "") -> Reply:
    """Parse a complete reply; raises PmacCommandError for ``ERRnnn``.

    Raises PmacProtocolError for anything else that is not a well-formed reply.
    """
    buf = bytes(buf)
    m = _ERR.search(buf)
    if m is not None:
        if m.end() != len(buf):
            raise PmacProtocolError(f"data after the error report: {buf!r}")
        raise PmacCommandError(int(m.group(1)), command, _lines(buf[:m.start()]))
    if buf and buf[-1] == BELL:      # I6=0 or 2: an error without its number
        raise PmacCommandError(0, command, _lines(buf[:-1]))
    if buf and buf[-1] == LF:
        raise PmacProtocolError(f"reply ended by LF, not ACK: the card is set to I3=1 (or 0); "
                                f"the driver needs I3=2: {buf[-40:]!r}")
    if not buf or buf[-1] != ACK:
        raise PmacProtocolError(f"reply not terminated by ACK: {buf[-40:]!r}")
    body = buf[:-1]
    if any(b < 0x20 and b not in (CR, LF) for b in body):
        raise PmacProtocolError(f"control character in reply: {body!r}")
    return Reply(_lines(body))


def format_constant(x: float, places: int = 9) -> str:
    """``x`` as a plain decimal for a command line: the card's ``{constant}`` is decimal
    (or ``$`` hex) and takes no exponent, so ``%g``'s ``2e-05`` would be refused (ERR003)."""
    if not isinstance(x, (int, float)) or x != x or x in (float("inf"), float("-inf")):
        raise PmacProtocolError(f"not a finite number: {x!r}")
    text = f"{float(x):.{places}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def parse_number(lines: list[str] | tuple[str, ...], what: str) -> float:
    """The single number of a one-line reply (``#1P``, ``I122``, ...)."""
    if len(lines) != 1:
        raise PmacProtocolError(f"{what}: expected one value, got {list(lines)!r}")
    try:
        return float(lines[0])
    except ValueError:
        raise PmacProtocolError(f"{what}: not a number: {lines[0]!r}") from None
