"""Dynamixel Protocol 2.0 packets: CRC-16, byte stuffing, building and parsing (no ROS).

Packet: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params... | CRC_L CRC_H`` where LEN counts
INST + params + CRC (after stuffing) and the CRC-16 (poly 0x8005, init 0, no reflection)
covers everything from the first header byte to the last parameter. Stuffing: inside
INST..params, every ``FF FF FD`` gets an extra ``FD``. Status packets use INST 0x55 and carry
the error byte as their first parameter. The driver never uses this module (it talks through
the official SDK); the emulator does, and tests use it to check bytes on the wire.
"""
from __future__ import annotations

from dataclasses import dataclass

from .errors import ProtocolError

__all__ = [
    "HEADER", "BROADCAST_ID", "MAX_ID",
    "INST_PING", "INST_READ", "INST_WRITE", "INST_REG_WRITE", "INST_ACTION",
    "INST_FACTORY_RESET", "INST_REBOOT", "INST_CLEAR", "INST_STATUS", "INST_SYNC_READ",
    "INST_SYNC_WRITE", "INST_FAST_SYNC_READ", "INST_BULK_READ", "INST_BULK_WRITE",
    "INST_FAST_BULK_READ", "INST_CONTROL_TABLE_BACKUP", "BYTE_GAP_TIMEOUT",
    "ERR_RESULT_FAIL", "ERR_INSTRUCTION", "ERR_CRC", "ERR_DATA_RANGE", "ERR_DATA_LENGTH",
    "ERR_DATA_LIMIT", "ERR_ACCESS", "ERRBIT_ALERT",
    "crc16", "stuff", "unstuff", "Packet", "build_packet", "build_status",
    "build_fast_sync_status", "PacketReader",
]

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_FACTORY_RESET = 0x06
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_CONTROL_TABLE_BACKUP = 0x20
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_FAST_SYNC_READ = 0x8A
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93
INST_FAST_BULK_READ = 0x9A

ERR_RESULT_FAIL = 1
ERR_INSTRUCTION = 2
ERR_CRC = 3
ERR_DATA_RANGE = 4
ERR_DATA_LENGTH = 5
ERR_DATA_LIMIT = 6
ERR_ACCESS = 7
ERRBIT_ALERT = 0x80


def _make_crc_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """Dynamixel CRC-16 of ``data`` (continuing from ``crc``)."""
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Byte-stuff INST+params: after every ``FF FF FD`` insert ``FD``.

    The check looks back into the output, so it also sees the header's ``FF FF FD`` only if
    included; callers pass INST+params alone, prefixed by the two bytes that precede them
    (``LEN_H``... never FF FF), which is what the protocol specifies.
    """
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-2] == 0xFF and out[-3] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Inverse of :func:`stuff`: drop the ``FD`` that follows every ``FF FF FD``."""
    out = bytearray()
    i = 0
    n = len(body)
    while i < n:
        b = body[i]
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-2] == 0xFF and out[-3] == 0xFF:
            if i + 1 < n and body[i + 1] == 0xFD:
                i += 1
        i += 1
    return bytes(out)


@dataclass(frozen=True)
class Packet:
    """A decoded packet: ``id``, ``instruction`` (0x55 for status) and unstuffed ``params``."""

    id: int
    instruction: int
    params: bytes
    crc_ok: bool = True

    @property
    def error(self) -> int:
        """Error byte of a status packet."""
        return self.params[0] if self.instruction == INST_STATUS and self.params else 0


def build_packet(dxl_id: int, instruction: int, params: bytes = b"", *,
                 stuffing: bool = True) -> bytes:
    """Encode a packet (stuffing INST+params unless ``stuffing`` is False)."""
    if not 0 <= dxl_id <= 0xFE:
        raise ProtocolError(f"ID must be 0..254, got {dxl_id}")
    body = bytes([instruction]) + bytes(params)
    if stuffing:
        body = stuff(body)
    length = len(body) + 2
    if length > 0xFFFF:
        raise ProtocolError(f"packet too long ({length} bytes)")
    head = HEADER + bytes([dxl_id, length & 0xFF, length >> 8])
    crc = crc16(head + body)
    return head + body + bytes([crc & 0xFF, crc >> 8])


def build_status(dxl_id: int, error: int, data: bytes = b"") -> bytes:
    """A status packet (INST 0x55) with ``error`` byte and ``data``."""
    return build_packet(dxl_id, INST_STATUS, bytes([error & 0xFF]) + bytes(data))


def build_fast_sync_status(items: list[tuple[int, int, bytes]]) -> bytes:
    """The single status packet of a Fast Sync Read for ``items`` = [(id, error, data)].

    Layout (ID 0xFE, INST 0x55): for each servo ``ERR ID DATA CRC`` where each servo's CRC
    is the running CRC of the packet up to its data, so the last one is the packet's CRC.
    Not stuffed (dynamixel-sdk 4.x does not unstuff fast replies).
    """
    if not items:
        raise ProtocolError("fast sync status needs at least one servo")
    length = 1 + sum(4 + len(d) for _, _, d in items)
    out = bytearray(HEADER + bytes([BROADCAST_ID, length & 0xFF, length >> 8, INST_STATUS]))
    crc = crc16(out)
    for dxl_id, error, data in items:
        seg = bytes([error & 0xFF, dxl_id]) + bytes(data)
        crc = crc16(seg, crc)
        out += seg + bytes([crc & 0xFF, crc >> 8])
        crc = crc16(out[-2:], crc)
    return bytes(out)


BYTE_GAP_TIMEOUT = 0.0015   # s: a servo drops a packet whose bytes come further apart
                            # (1.5 ms between the bytes of a packet: the e-Manual's
                            # Protocol 2.0 rule as issue 24 item 9 quotes it; the passage
                            # itself was not among the references searched)


class PacketReader:
    """Incremental decoder of a byte stream into packets, as a servo's receiver does it.

    ``feed(data, now)`` returns the packets completed by ``data``. Garbage before a header
    is skipped. A packet with a bad CRC is returned with ``crc_ok=False`` (the servo answers
    a CRC Error) and counted in ``crc_errors``. An incomplete packet (a packet split by the
    host with a pause, or a corrupt length field announcing 4000 bytes) is dropped when the
    next bytes come more than ``BYTE_GAP_TIMEOUT`` after the previous ones (counted in
    ``timeouts``), and those bytes are read afresh, as by a servo (without ``now``, nothing
    times out).

    ``now`` (s) is when ``data`` was taken, the latest it can have arrived; ``arrived_after``
    (default ``now``) the earliest: a reader polling a port knows only that the bytes came
    after it last saw the port empty. The gap is measured from the previous ``now`` to this
    ``arrived_after``: a lower bound of the true gap, so a process that was not scheduled
    for a while never drops a packet a servo would have taken.
    """

    MAX_LENGTH = 4096

    def __init__(self) -> None:
        self._buf = bytearray()
        self._last = 0.0       # when the buffered bytes were taken (latest arrival)
        self.crc_errors = 0
        self.timeouts = 0
        self.packets = 0
        self.bytes = 0         # bytes fed
        self.last_gap: float | None = None   # s, the gap judged last (bytes after a part)

    def feed(self, data: bytes, now: float | None = None,
             arrived_after: float | None = None) -> list[Packet]:
        if now is not None:
            start = now if arrived_after is None else min(arrived_after, now)
            if self._buf:
                self.last_gap = start - self._last
                if self.last_gap > BYTE_GAP_TIMEOUT:
                    self._buf.clear()
                    self.timeouts += 1
            self._last = now
        self.bytes += len(data)
        return self._parse(data)

    def _parse(self, data: bytes) -> list[Packet]:
        self._buf += data
        out: list[Packet] = []
        while True:
            start = self._buf.find(b"\xff\xff\xfd")
            if start < 0:
                # keep a possible partial header at the end
                keep = 2 if self._buf.endswith(b"\xff\xff") else 1 if self._buf.endswith(b"\xff") else 0
                del self._buf[:len(self._buf) - keep]
                return out
            if start:
                del self._buf[:start]
            if len(self._buf) < 7:
                return out
            if self._buf[3] != 0x00:  # FF FF FD FD ... is stuffed data, not a header
                del self._buf[:3]
                continue
            length = self._buf[5] | self._buf[6] << 8
            if length < 3 or length > self.MAX_LENGTH:
                del self._buf[:3]
                continue
            total = 7 + length
            if len(self._buf) < total:
                return out
            raw = bytes(self._buf[:total])
            crc = raw[-2] | raw[-1] << 8
            del self._buf[:total]
            body = unstuff(raw[7:-2])
            if crc16(raw[:-2]) != crc:
                self.crc_errors += 1
                out.append(Packet(raw[4], body[0], body[1:], crc_ok=False))
                continue
            self.packets += 1
            out.append(Packet(raw[4], body[0], body[1:]))
