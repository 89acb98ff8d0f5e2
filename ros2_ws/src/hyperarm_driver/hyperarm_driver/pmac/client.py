"""Blocking Turbo PMAC clients: Ethernet (TCP, port 1025) and, optionally, RS-232.

Both give the same call, ``command("#1P#1V") -> ["1234.5", "0"]``: one command line in, its
response lines out, ``PmacCommandError`` for an ``ERRnnn`` reply, ``PmacLinkError`` (or its
subclass ``PmacTimeoutError``) when the link is unusable. After a link error the client has
closed its socket; the next call reconnects if ``auto_reconnect`` (default), so a caller
simply retries later. Thread-safe: one command at a time.

Every reply form of a real card is handled (see :mod:`.protocol`): ``<STX>text<CR>`` lines
the card sends on its own are taken out of the reply and kept in :attr:`messages`; a NUL
(busy, the command was not taken) makes the client send the command again every 2 ms until
the reply timeout, then raise ``PmacBusyError`` (a ``PmacTimeoutError``); the FLUSH
acknowledgement is any one byte.
"""
from __future__ import annotations

import collections
import socket
import threading
import time
from typing import Any

from . import protocol as proto
from .errors import PmacBusyError, PmacError, PmacLinkError, PmacProtocolError, \
    PmacTimeoutError

__all__ = ["PmacClient", "PmacSerialClient", "DEFAULT_PORT", "BUSY_RETRY"]

DEFAULT_PORT = 1025
BUSY_RETRY = 0.002     # s, pause before sending a command again after a NUL (busy) reply


class _Base:
    """Timing, validation and statistics shared by the transports."""

    def __init__(self, timeout: float) -> None:
        if not 0.0 < timeout <= 60.0:
            raise ValueError(f"timeout must be within (0, 60] s, got {timeout}")
        self.timeout = float(timeout)
        self._lock = threading.Lock()
        self.commands_sent = 0
        self.busy_replies = 0
        self.last_round_trip = float("nan")   # s, last successful command
        self.messages: collections.deque[str] = collections.deque(maxlen=100)

    def command(self, command: str) -> list[str]:  # pragma: no cover - overridden
        raise NotImplementedError

    def query_float(self, command: str) -> float:
        """A command expected to answer exactly one number."""
        return proto.parse_number(self.command(command), command)

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError


class PmacClient(_Base):
    """Turbo PMAC Ethernet client (VR_PMAC_GETRESPONSE / GETBUFFER / FLUSH).

    ``timeout`` (s) bounds the whole reply of one command; ``connect_timeout`` (s) bounds a
    connection attempt. Constructing does not connect: call :meth:`connect` or just
    :meth:`command`.
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, timeout: float = 0.1,
                 connect_timeout: float = 1.0, auto_reconnect: bool = True) -> None:
        super().__init__(timeout)
        if not 0 < int(port) < 65536:
            raise ValueError(f"port must be within 1..65535, got {port}")
        if not 0.0 < connect_timeout <= 60.0:
            raise ValueError(f"connect_timeout must be within (0, 60] s, got {connect_timeout}")
        self.host = str(host)
        self.port = int(port)
        self.connect_timeout = float(connect_timeout)
        self.auto_reconnect = bool(auto_reconnect)
        self._sock: socket.socket | None = None
        self.connects = 0

    @property
    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        return self._sock is not None

    # -- link -----------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the TCP connection (if not open) and flush the card's output buffers."""
        with self._lock:
            self._connect_locked()

    def _connect_locked(self) -> None:
        if self._sock is not None:
            return
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as exc:
            raise PmacLinkError(f"cannot connect to PMAC at {self.endpoint}: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        self.connects += 1
        try:
            self._flush_locked()
        except PmacError:
            self._drop()
            raise

    def close(self) -> None:
        with self._lock:
            self._drop()

    def _drop(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    # -- requests -------------------------------------------------------------------------
    def flush(self) -> None:
        """VR_PMAC_FLUSH: discard pending output on the card."""
        with self._lock:
            if self._sock is None:
                self._connect_locked()   # connecting flushes
                return
            self._flush_locked()

    def _flush_locked(self) -> None:
        deadline = time.monotonic() + self.timeout
        self._send(proto.flush_packet())
        got = self._recv_some(deadline, 1)      # "one byte is returned": ^X echo, '@', ...
        if len(got) != 1:
            self._drop()
            raise PmacProtocolError(f"FLUSH answered {got!r}, expected one byte")

    def command(self, command: str) -> list[str]:
        """Send one on-line command line; return its response lines.

        Raises PmacCommandError (ERRnnn: the link stays up), PmacProtocolError (bad command
        text: nothing sent; or a garbled reply: link dropped), PmacLinkError /
        PmacTimeoutError (link dropped; a later call reconnects).
        """
        packet = proto.getresponse_packet(command)   # validates before anything is sent
        with self._lock:
            if self._sock is None:
                if not self.auto_reconnect:
                    raise PmacLinkError(f"not connected to PMAC at {self.endpoint}")
                self._connect_locked()
            t0 = time.perf_counter()
            deadline = time.monotonic() + self.timeout
            busy = 0
            while True:
                self._send(packet)
                try:
                    buf = self._receive_reply(deadline)
                except PmacTimeoutError as exc:
                    if not busy:
                        raise
                    raise PmacBusyError(f"PMAC at {self.endpoint} busy (NUL replies) for "
                                        f"{self.timeout:g} s") from exc
                if not proto.is_busy(buf):
                    break
                busy += 1
                self.busy_replies += 1
                if time.monotonic() + BUSY_RETRY >= deadline:
                    self._drop()
                    raise PmacBusyError(f"PMAC at {self.endpoint} busy (NUL replies) for "
                                        f"{self.timeout:g} s")
                time.sleep(BUSY_RETRY)
            try:
                reply = proto.parse_reply(buf, command)
            except PmacProtocolError:
                self._drop()                           # stream state unknown: resync
                raise
            finally:
                self.commands_sent += 1
            self.last_round_trip = time.perf_counter() - t0
            return list(reply.lines)

    def _receive_reply(self, deadline: float) -> bytes:
        """One whole reply (STX lines moved to :attr:`messages`), fetching GETBUFFER pieces."""
        buf = bytearray()
        chunk = 0
        while True:
            data = self._recv_some(deadline, proto.REPLY_CHUNK - chunk)
            buf += data
            chunk += len(data)
            msgs, rest = proto.split_messages(buf)
            if msgs:
                self.messages.extend(msgs)
                buf = bytearray(rest)
                if not buf:              # the card stopped after the message line
                    self._send(proto.getbuffer_packet())
                    chunk = 0
                    continue
            if proto.reply_complete(buf):
                return bytes(buf)
            if chunk >= proto.REPLY_CHUNK:        # long reply: ask for the next piece
                self._send(proto.getbuffer_packet())
                chunk = 0

    def _send(self, packet: bytes) -> None:
        assert self._sock is not None
        try:
            self._sock.sendall(packet)
        except OSError as exc:
            self._drop()
            raise PmacLinkError(f"PMAC link {self.endpoint} lost while sending: {exc}") from exc

    def _recv_some(self, deadline: float, maxlen: int = proto.REPLY_CHUNK) -> bytes:
        assert self._sock is not None
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            self._drop()
            raise PmacTimeoutError(f"PMAC at {self.endpoint}: no reply within {self.timeout:g} s")
        try:
            self._sock.settimeout(remaining)
            data = self._sock.recv(max(1, maxlen))
        except socket.timeout:
            self._drop()
            raise PmacTimeoutError(
                f"PMAC at {self.endpoint}: no reply within {self.timeout:g} s") from None
        except OSError as exc:
            self._drop()
            raise PmacLinkError(f"PMAC link {self.endpoint} lost: {exc}") from exc
        if not data:
            self._drop()
            raise PmacLinkError(f"PMAC at {self.endpoint} closed the connection")
        return data


class PmacSerialClient(_Base):
    """The same command layer over the card's RS-232 port (needs ``pyserial``).

    Set the card for I3=2 (ACK-terminated replies, CR line ends) and I6=1 (ERRnnn reports).
    Each command is sent followed by CR; the reply ends with ACK or BELL ERRnnn CR.
    ``port`` is anything ``serial.serial_for_url`` accepts (``/dev/ttyS0``, a pty, ...).
    """

    def __init__(self, port: str, baudrate: int = 38400, timeout: float = 0.1) -> None:
        super().__init__(timeout)
        self.port = str(port)
        self.baudrate = int(baudrate)
        self._ser: Any = None

    @property
    def endpoint(self) -> str:
        return f"{self.port}@{self.baudrate}"

    @property
    def connected(self) -> bool:
        return self._ser is not None

    def connect(self) -> None:
        with self._lock:
            self._open_locked()

    def _open_locked(self) -> None:
        if self._ser is not None:
            return
        try:
            import serial  # pyserial, a dependency of dynamixel-sdk
        except ImportError as exc:  # pragma: no cover - environment dependent
            raise PmacLinkError("pyserial is not installed") from exc
        try:
            self._ser = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0)
        except (OSError, ValueError, serial.SerialException) as exc:
            raise PmacLinkError(f"cannot open PMAC serial port {self.endpoint}: {exc}") from exc
        self._ser.reset_input_buffer()

    def close(self) -> None:
        with self._lock:
            self._close_quietly()

    def _close_quietly(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except OSError:
                pass
            finally:
                self._ser = None

    def command(self, command: str) -> list[str]:
        data = proto.check_command(command) + b"\r"
        with self._lock:
            self._open_locked()
            t0 = time.perf_counter()
            deadline = time.monotonic() + self.timeout
            buf = bytearray()
            try:
                self._ser.write(data)
                while not proto.reply_complete(buf):
                    if time.monotonic() > deadline:
                        raise PmacTimeoutError(
                            f"PMAC at {self.endpoint}: no reply within {self.timeout:g} s")
                    self._ser.timeout = max(0.0, deadline - time.monotonic())
                    buf += self._ser.read(max(1, self._ser.in_waiting))
                    msgs, rest = proto.split_messages(buf)
                    if msgs:
                        self.messages.extend(msgs)
                        buf = bytearray(rest)
                if proto.is_busy(buf):
                    self.busy_replies += 1
                    raise PmacBusyError(f"PMAC at {self.endpoint} busy (NUL reply)")
            except PmacTimeoutError:   # (PmacBusyError too)
                self._close_quietly()
                raise
            except OSError as exc:
                self._close_quietly()
                raise PmacLinkError(f"PMAC serial link {self.endpoint} lost: {exc}") from exc
            self.commands_sent += 1
            try:
                reply = proto.parse_reply(bytes(buf), command)
            except PmacProtocolError:
                self._close_quietly()     # resynchronise on the next call
                raise
            self.last_round_trip = time.perf_counter() - t0
            return list(reply.lines)
