"""The IDX USB command set (guide 2.1) as frozen dataclasses with struct codecs.

Requests travel host -> IDX with their OpCode; every reply has OpCode 0x00 and starts with the
error DWORD of chapter 6. Both directions are here because the device decodes requests and
encodes replies while the host client does the reverse.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar, Self

from gatewaylab.common.errors import LocalError
from gatewaylab.devices.maxon_idx.codec import Frame
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode

__all__ = [
    "CONTROL_LAST",
    "CONTROL_TOGGLE",
    "MAX_SEGMENT",
    "REPLY_TYPE",
    "RESPONSE_OPCODE",
    "InitiateSegmentedRead",
    "InitiateSegmentedReadReply",
    "InitiateSegmentedWrite",
    "NmtCommand",
    "OpCode",
    "ReadLss",
    "ReadLssReply",
    "ReadObject",
    "ReadObjectReply",
    "Reply",
    "Request",
    "SegmentRead",
    "SegmentReadReply",
    "SegmentWrite",
    "SegmentWriteReply",
    "SendLss",
    "SendNmtService",
    "StatusReply",
    "WriteObject",
    "decode_reply",
    "decode_request",
    "error_reply",
]


RESPONSE_OPCODE = 0x00
#: Largest data block of one segment (guide 2.1.1.2/2.1.1.3/2.1.2.3: "Length (max. 255 bytes)").
MAX_SEGMENT = 255

CONTROL_TOGGLE = 0x01
CONTROL_LAST = 0x02


class OpCode(IntEnum):
    """USB frame opcodes (guide chapter 2)."""
    READ_OBJECT = 0x60
    INITIATE_SEGMENTED_READ = 0x81
    SEGMENT_READ = 0x62
    WRITE_OBJECT = 0x68
    INITIATE_SEGMENTED_WRITE = 0x69
    SEGMENT_WRITE = 0x6A
    SEND_NMT_SERVICE = 0x70
    SEND_LSS = 0x7A
    READ_LSS = 0x7B


class NmtCommand(IntEnum):
    """SendNMTService CmdSpecifier values (guide 2.1.2.4, table 3-12)."""

    START_REMOTE_NODE = 1
    STOP_REMOTE_NODE = 2
    ENTER_PRE_OPERATIONAL = 128
    RESET_NODE = 129
    RESET_COMMUNICATION = 130


_OBJ = struct.Struct("<BHB")
_OBJ_DATA = struct.Struct("<BHB4s")
_OBJ_LEN = struct.Struct("<BHBI")
_CTRL = struct.Struct("<BB")
_NMT = struct.Struct("<HH")
_U16 = struct.Struct("<H")
_ERR = struct.Struct("<I")
_ERR_DATA4 = struct.Struct("<I4s")
_ERR_LSS = struct.Struct("<I8s")
_ERR_TOTAL_LEN = struct.Struct("<IIB")
_ERR_LEN_CTRL = struct.Struct("<IBB")


def _pad(data: bytes) -> bytes:
    """Pad to whole words with the guide's "dummy byte when length odd"."""
    return data + b"\x00" if len(data) % 2 else data


def _need_len(frame: Frame, *allowed: int) -> None:
    if frame.length not in allowed:
        raise IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH,
                             f"opcode 0x{frame.opcode:02X} with Len {frame.length}, expected {allowed}")


def _check_field(name: str, value: int, bits: int) -> None:
    """A request field must fit its BYTE / WORD / DWORD (guide 2.1); LocalError names the field."""
    top = (1 << bits) - 1
    if not 0 <= value <= top:
        raise LocalError(f"{name} {value:#x} outside 0..{top:#x}")


def _check_object(node_id: int, index: int, subindex: int) -> None:
    _check_field("node id", node_id, 8)
    _check_field("index", index, 16)
    _check_field("subindex", subindex, 8)


def _check_segment(data: bytes) -> None:
    if len(data) > MAX_SEGMENT:
        raise LocalError(f"a segment carries at most {MAX_SEGMENT} bytes, got {len(data)}")


# -- requests ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class _ObjectRequest:
    """A request that is only an object address: node (WORD low byte), index, subindex (2 words)."""

    opcode: ClassVar[OpCode]
    node_id: int
    index: int
    subindex: int

    def __post_init__(self) -> None:
        _check_object(self.node_id, self.index, self.subindex)

    def to_frame(self) -> Frame:
        return Frame(self.opcode, _OBJ.pack(self.node_id, self.index, self.subindex))

    @classmethod
    def from_frame(cls, frame: Frame) -> Self:
        _need_len(frame, 2)
        return cls(*_OBJ.unpack(frame.data))


@dataclass(frozen=True, slots=True)
class ReadObject(_ObjectRequest):
    """2.1.1.1: read up to 4 bytes of an object."""

    opcode: ClassVar[OpCode] = OpCode.READ_OBJECT


@dataclass(frozen=True, slots=True)
class InitiateSegmentedRead(_ObjectRequest):
    """2.1.1.2: start reading an object of any size."""

    opcode: ClassVar[OpCode] = OpCode.INITIATE_SEGMENTED_READ


@dataclass(frozen=True, slots=True)
class SegmentRead:
    """2.1.1.3: fetch the next segment; ``toggle`` is control bit 0."""

    opcode: ClassVar[OpCode] = OpCode.SEGMENT_READ
    toggle: bool

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(self.opcode, _CTRL.pack(CONTROL_TOGGLE if self.toggle else 0, 0))

    @classmethod
    def from_frame(cls, frame: Frame) -> SegmentRead:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        _need_len(frame, 1)
        control, _dummy = _CTRL.unpack(frame.data)
        return cls(bool(control & CONTROL_TOGGLE))


@dataclass(frozen=True, slots=True)
class WriteObject:
    """2.1.2.1: write up to 4 bytes (always 4 on the wire)."""

    opcode: ClassVar[OpCode] = OpCode.WRITE_OBJECT
    node_id: int
    index: int
    subindex: int
    data: bytes

    def __post_init__(self) -> None:
        _check_object(self.node_id, self.index, self.subindex)
        if len(self.data) != 4:
            raise LocalError("WriteObject carries exactly 4 data bytes (pad with zeros)")

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(self.opcode, _OBJ_DATA.pack(self.node_id, self.index, self.subindex, self.data))

    @classmethod
    def from_frame(cls, frame: Frame) -> WriteObject:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        _need_len(frame, 4)
        return cls(*_OBJ_DATA.unpack(frame.data))


@dataclass(frozen=True, slots=True)
class InitiateSegmentedWrite:
    """2.1.2.2: announce ``total_length`` bytes to come in SegmentWrite commands."""

    opcode: ClassVar[OpCode] = OpCode.INITIATE_SEGMENTED_WRITE
    node_id: int
    index: int
    subindex: int
    total_length: int

    def __post_init__(self) -> None:
        _check_object(self.node_id, self.index, self.subindex)
        _check_field("total length", self.total_length, 32)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(self.opcode, _OBJ_LEN.pack(self.node_id, self.index, self.subindex, self.total_length))

    @classmethod
    def from_frame(cls, frame: Frame) -> InitiateSegmentedWrite:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        _need_len(frame, 4)
        return cls(*_OBJ_LEN.unpack(frame.data))


@dataclass(frozen=True, slots=True)
class SegmentWrite:
    """2.1.2.3: one segment of up to 255 bytes, control bit 0 toggle, bit 1 last segment."""

    opcode: ClassVar[OpCode] = OpCode.SEGMENT_WRITE
    toggle: bool
    last: bool
    data: bytes

    def __post_init__(self) -> None:
        _check_segment(self.data)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        control = (CONTROL_TOGGLE if self.toggle else 0) | (CONTROL_LAST if self.last else 0)
        return Frame(self.opcode, _pad(_CTRL.pack(len(self.data), control) + self.data))

    @classmethod
    def from_frame(cls, frame: Frame) -> SegmentWrite:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        if frame.length < 1:
            _need_len(frame, 1)
        length, control = _CTRL.unpack_from(frame.data)
        _need_len(frame, (2 + length + 1) // 2)
        return cls(bool(control & CONTROL_TOGGLE), bool(control & CONTROL_LAST), frame.data[2:2 + length])


@dataclass(frozen=True, slots=True)
class SendNmtService:
    """2.1.2.4: put an NMT command on the bus (node 0 = all nodes)."""

    opcode: ClassVar[OpCode] = OpCode.SEND_NMT_SERVICE
    node_id: int
    command: int

    def __post_init__(self) -> None:
        _check_field("node id", self.node_id, 16)
        _check_field("command specifier", self.command, 16)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(self.opcode, _NMT.pack(self.node_id, self.command))

    @classmethod
    def from_frame(cls, frame: Frame) -> SendNmtService:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        _need_len(frame, 2)
        return cls(*_NMT.unpack(frame.data))


@dataclass(frozen=True, slots=True)
class SendLss:
    """2.1.3.1: the 8 bytes of an LSS master message (COB-ID 0x7E5)."""

    opcode: ClassVar[OpCode] = OpCode.SEND_LSS
    data: bytes

    def __post_init__(self) -> None:
        if len(self.data) != 8:
            raise LocalError("an LSS master message has exactly 8 bytes")

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(self.opcode, self.data)

    @classmethod
    def from_frame(cls, frame: Frame) -> SendLss:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        _need_len(frame, 4)
        return cls(frame.data)


@dataclass(frozen=True, slots=True)
class ReadLss:
    """2.1.3.2: wait up to ``timeout_ms`` for an LSS slave message (COB-ID 0x7E4)."""

    opcode: ClassVar[OpCode] = OpCode.READ_LSS
    timeout_ms: int

    def __post_init__(self) -> None:
        _check_field("timeout", self.timeout_ms, 16)

    def to_frame(self) -> Frame:
        # Len 2 as the guide's table says: the timeout WORD and a zero WORD.
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(self.opcode, _U16.pack(self.timeout_ms) + b"\x00\x00")

    @classmethod
    def from_frame(cls, frame: Frame) -> ReadLss:
        # The guide's table says Len 2 but lists one WORD: accept both, the first word is the timeout.
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        _need_len(frame, 1, 2)
        return cls(_U16.unpack_from(frame.data)[0])


Request = (ReadObject | InitiateSegmentedRead | SegmentRead | WriteObject | InitiateSegmentedWrite
           | SegmentWrite | SendNmtService | SendLss | ReadLss)

_REQUESTS: dict[int, type[Request]] = {
    cls.opcode: cls for cls in (ReadObject, InitiateSegmentedRead, SegmentRead, WriteObject,
                                InitiateSegmentedWrite, SegmentWrite, SendNmtService, SendLss, ReadLss)
}


def decode_request(frame: Frame) -> Request:
    """The request in ``frame``; IdxRemoteError with the reply's code when it is not one."""
    cls = _REQUESTS.get(frame.opcode)
    if cls is None:
        raise IdxRemoteError(SdoAbortCode.ILLEGAL_COMMAND, f"unknown opcode 0x{frame.opcode:02X}")
    return cls.from_frame(frame)


# -- replies ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class StatusReply:
    """Len 2 reply: just the error DWORD (WriteObject, InitiateSegmentedWrite, SendNMTService,
    SendLSS, and the CRC / unknown-opcode error frames)."""

    error: int = 0

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(RESPONSE_OPCODE, _ERR.pack(self.error))

    @classmethod
    def from_frame(cls, frame: Frame) -> StatusReply:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        return cls(_ERR.unpack_from(frame.data)[0])


@dataclass(frozen=True, slots=True)
class ReadObjectReply:
    """2.1.1.1 reply: error DWORD and up to 4 data bytes."""
    error: int = 0
    data: bytes = bytes(4)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(RESPONSE_OPCODE, _ERR_DATA4.pack(self.error, self.data.ljust(4, b"\x00")))

    @classmethod
    def from_frame(cls, frame: Frame) -> ReadObjectReply:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        if frame.length < 4:
            return cls(StatusReply.from_frame(frame).error)
        return cls(*_ERR_DATA4.unpack_from(frame.data))


@dataclass(frozen=True, slots=True)
class InitiateSegmentedReadReply:
    """2.1.1.2 reply: error DWORD, total length and the first segment."""
    error: int = 0
    total_length: int = 0
    data: bytes = b""

    def __post_init__(self) -> None:
        _check_segment(self.data)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(RESPONSE_OPCODE, _pad(_ERR_TOTAL_LEN.pack(self.error, self.total_length, len(self.data))
                                           + self.data))

    @classmethod
    def from_frame(cls, frame: Frame) -> InitiateSegmentedReadReply:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        if frame.length < 5:
            return cls(StatusReply.from_frame(frame).error)
        error, total, n = _ERR_TOTAL_LEN.unpack_from(frame.data)
        return cls(error, total, frame.data[9:9 + n])


@dataclass(frozen=True, slots=True)
class SegmentReadReply:
    """2.1.1.3 reply: error DWORD, control byte (toggle, last) and a segment."""
    error: int = 0
    toggle: bool = False
    last: bool = False
    data: bytes = b""

    def __post_init__(self) -> None:
        _check_segment(self.data)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        control = (CONTROL_TOGGLE if self.toggle else 0) | (CONTROL_LAST if self.last else 0)
        head = _ERR_LEN_CTRL.pack(self.error, len(self.data), control)
        return Frame(RESPONSE_OPCODE, _pad(head + self.data))

    @classmethod
    def from_frame(cls, frame: Frame) -> SegmentReadReply:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        if frame.length < 3:
            return cls(StatusReply.from_frame(frame).error)
        error, n, control = _ERR_LEN_CTRL.unpack_from(frame.data)
        return cls(error, bool(control & CONTROL_TOGGLE), bool(control & CONTROL_LAST), frame.data[6:6 + n])


@dataclass(frozen=True, slots=True)
class SegmentWriteReply:
    """2.1.2.3 reply: error DWORD and the number of bytes taken."""
    error: int = 0
    length_written: int = 0
    toggle: bool = False

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(RESPONSE_OPCODE, _ERR_LEN_CTRL.pack(self.error, self.length_written,
                                                         CONTROL_TOGGLE if self.toggle else 0))

    @classmethod
    def from_frame(cls, frame: Frame) -> SegmentWriteReply:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        if frame.length < 3:
            return cls(StatusReply.from_frame(frame).error)
        error, n, control = _ERR_LEN_CTRL.unpack_from(frame.data)
        return cls(error, n, bool(control & CONTROL_TOGGLE))


@dataclass(frozen=True, slots=True)
class ReadLssReply:
    """2.1.3.2 reply: error DWORD and the LSS slave message."""
    error: int = 0
    data: bytes = bytes(8)

    def to_frame(self) -> Frame:
        """The frame as it goes on the USB link (guide chapter 2)."""
        return Frame(RESPONSE_OPCODE, _ERR_LSS.pack(self.error, self.data))

    @classmethod
    def from_frame(cls, frame: Frame) -> ReadLssReply:
        """Decode a received frame (IdxRemoteError 0x06070010 when it is too short)."""
        if frame.length < 6:
            return cls(StatusReply.from_frame(frame).error)
        return cls(*_ERR_LSS.unpack_from(frame.data))


Reply = (StatusReply | ReadObjectReply | InitiateSegmentedReadReply | SegmentReadReply
         | SegmentWriteReply | ReadLssReply)

#: The reply layout of each request (guide 2.1); used by the host to decode and by the device to
#: build an error reply that keeps the command's layout.
REPLY_TYPE: dict[int, type[Reply]] = {
    OpCode.READ_OBJECT: ReadObjectReply,
    OpCode.INITIATE_SEGMENTED_READ: InitiateSegmentedReadReply,
    OpCode.SEGMENT_READ: SegmentReadReply,
    OpCode.WRITE_OBJECT: StatusReply,
    OpCode.INITIATE_SEGMENTED_WRITE: StatusReply,
    OpCode.SEGMENT_WRITE: SegmentWriteReply,
    OpCode.SEND_NMT_SERVICE: StatusReply,
    OpCode.SEND_LSS: StatusReply,
    OpCode.READ_LSS: ReadLssReply,
}


def error_reply(opcode: int, code: int) -> Reply:
    """The reply to ``opcode`` carrying ``code`` with empty/zero data (Len 2 for unknown opcodes)."""
    cls = REPLY_TYPE.get(opcode, StatusReply)
    return cls(code)


def decode_reply(opcode: int, frame: Frame) -> Reply:
    """Decode the reply to a request with ``opcode``; a Len 2 reply decodes to its error only."""
    if frame.opcode != RESPONSE_OPCODE:
        raise IdxRemoteError(SdoAbortCode.GENERAL_ERROR, f"reply opcode 0x{frame.opcode:02X}, expected 0x00")
    if frame.length < 2:
        raise IdxRemoteError(SdoAbortCode.GENERAL_ERROR, f"reply of {frame.length} words has no error DWORD")
    return REPLY_TYPE.get(opcode, StatusReply).from_frame(frame)
