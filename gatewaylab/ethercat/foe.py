"""File access over EtherCAT: read/write requests, data/ack/busy/error packets (ETG.1000.6 FoE).

Packets: opcode u8, reserved u8, then u32 (password for RRQ/WRQ, packet number for DATA/ACK,
error code for ERR, done/entire u16 pair for BUSY) and the rest (file name, data, error text).
A DATA packet shorter than the mailbox allows ends a transfer. What a file *means* (firmware,
configuration) is up to the device: it answers through a :class:`FoeHandler`.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, field
from typing import Protocol

from gatewaylab.ethercat.errors import FoeBusy, FoeError, FoeErrorCode, FrameFormatError

__all__ = ["FOE_BUSY", "FOE_HEADER", "FoeFiles", "FoeHandler", "FoeOpcode", "FoeServer", "foe_packet"]


FOE_HEADER = struct.Struct("<BBI")
FOE_BUSY = struct.Struct("<BBHH")


class FoeOpcode(enum.IntEnum):
    """FoE opcodes (ETG.1000.6)."""
    RRQ = 1
    WRQ = 2
    DATA = 3
    ACK = 4
    ERR = 5
    BUSY = 6


def foe_packet(opcode: int, word: int, rest: bytes = b"") -> bytes:
    """An FoE packet: opcode, reserved, password/packet number/error code, rest."""
    return FOE_HEADER.pack(opcode, 0, word & 0xFFFFFFFF) + rest


class FoeHandler(Protocol):
    """What a device does with files; raise FoeError with an FoE error code to refuse.

    A handler may also define ``foe_check_write(name, password)``: called on the write request,
    it refuses with FoeError before any data packet (e.g. a firmware file outside BOOT).
    """

    def foe_read(self, name: str, password: int) -> bytes:
        """The file's contents (FoeError to refuse)."""
    def foe_write(self, name: str, password: int, data: bytes) -> None:
        """Store a received file (FoeError to refuse, FoeBusy to ask for time)."""


@dataclass
class FoeFiles:
    """A simple file store: any name may be written, read back, optionally password protected."""

    files: dict[str, bytes] = field(default_factory=dict)
    passwords: dict[str, int] = field(default_factory=dict)
    max_size: int = 1 << 20

    def _check(self, name: str, password: int) -> None:
        want = self.passwords.get(name)
        if want is not None and want != password:
            raise FoeError(f"wrong password for {name!r}", FoeErrorCode.NO_RIGHTS)

    def foe_read(self, name: str, password: int) -> bytes:
        """The stored file, FoE 'not found' otherwise."""
        self._check(name, password)
        if name not in self.files:
            raise FoeError(f"no file {name!r}", FoeErrorCode.NOT_FOUND)
        return self.files[name]

    def foe_write(self, name: str, password: int, data: bytes) -> None:
        """Keep the file in memory."""
        self._check(name, password)
        if len(data) > self.max_size:
            raise FoeError(f"{name!r} too large", FoeErrorCode.DISK_FULL)
        self.files[name] = data


class _Mode(enum.Enum):
    IDLE = 0
    WRITING = 1
    READING = 2


class FoeServer:
    """One slave's FoE endpoint (one transfer at a time)."""

    def __init__(self, handler: FoeHandler, mailbox_size: int) -> None:
        self.handler = handler
        self.max_data = mailbox_size - 6 - FOE_HEADER.size
        self.mode = _Mode.IDLE
        self._name = ""
        self._password = 0
        self._buf = bytearray()
        self._packet = 0
        self._last_len = 0
        self._finishing = False
        self.errors_sent = 0

    def reset(self) -> None:
        """Forget a transfer in progress (mailbox reset)."""
        self.mode = _Mode.IDLE
        self._buf = bytearray()
        self._finishing = False

    def _error(self, code: int, text: str = "") -> list[bytes]:
        self.reset()
        self.errors_sent += 1
        return [foe_packet(FoeOpcode.ERR, code, text.encode("latin-1", "replace"))]

    def handle(self, data: bytes) -> list[bytes]:
        """One FoE mailbox message in, the replies out."""
        if len(data) < FOE_HEADER.size:
            raise FrameFormatError("FoE header missing")
        opcode, _res, word = FOE_HEADER.unpack_from(data, 0)
        rest = data[FOE_HEADER.size:]
        try:
            if opcode == FoeOpcode.WRQ:
                self.reset()
                self._name = rest.decode("latin-1").rstrip("\0")
                self._password = word
                check = getattr(self.handler, "foe_check_write", None)
                if check is not None:
                    check(self._name, word)  # optional: refuse at the request, before any data
                self.mode = _Mode.WRITING
                self._packet = 0
                return [foe_packet(FoeOpcode.ACK, 0)]
            if opcode == FoeOpcode.RRQ:
                self.reset()
                self._name = rest.decode("latin-1").rstrip("\0")
                self._buf = bytearray(self.handler.foe_read(self._name, word))
                self.mode = _Mode.READING
                self._packet = 0
                return [self._next_data()]
            if opcode == FoeOpcode.DATA:
                if self.mode != _Mode.WRITING:
                    return self._error(FoeErrorCode.ILLEGAL, "no write in progress")
                retry = self._finishing and word == self._packet
                if not retry and word != self._packet + 1:
                    return self._error(FoeErrorCode.PACKET_NUMBER_WRONG, "packet number")
                if not retry:
                    self._packet = word
                    self._buf.extend(rest)
                if len(rest) < self.max_data:
                    self._finishing = True
                    try:
                        self.handler.foe_write(self._name, self._password, bytes(self._buf))
                    except FoeBusy as busy:
                        return [FOE_BUSY.pack(FoeOpcode.BUSY, 0, busy.done & 0xFFFF, busy.entire & 0xFFFF)]
                    self.reset()
                return [foe_packet(FoeOpcode.ACK, word)]
            if opcode == FoeOpcode.ACK:
                if self.mode != _Mode.READING or word != self._packet:
                    return self._error(FoeErrorCode.ILLEGAL, "unexpected ack")
                if self._last_len < self.max_data:
                    self.reset()
                    return []
                return [self._next_data()]
            if opcode == FoeOpcode.ERR:
                self.reset()
                return []
            return self._error(FoeErrorCode.ILLEGAL, f"opcode {opcode}")
        except FoeError as exc:
            return self._error(exc.code if exc.code is not None else FoeErrorCode.NOT_DEFINED, str(exc))

    def _next_data(self) -> bytes:
        chunk = bytes(self._buf[:self.max_data])
        del self._buf[:len(chunk)]
        self._packet += 1
        self._last_len = len(chunk)
        return foe_packet(FoeOpcode.DATA, self._packet, chunk)
