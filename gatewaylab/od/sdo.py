"""The SDO protocol's codec and transfer state, shared by the CANopen SDO server and client and CoE.

CiA 301 7.2.4 defines the command byte, the expedited/segmented transfers and the block
transfers; ETG.1000.6 CoE carries the same SDO in a mailbox (segments may be longer than 7
bytes, an initiate upload response may carry the first part of the data). What is the same lives
here: named command specifiers, pure encode/decode functions, the two server-side segmented
transfer state machines (:class:`SegmentedDownload`, :class:`SegmentedUpload`) and their two
client-side counterparts (:class:`ClientSegmentedUpload`, :class:`ClientSegmentedDownload`) used by
the CANopen SDO client and the EtherCAT master, and the two halves of a block transfer
(:class:`BlockSender`, :class:`BlockReceiver`), which the CANopen server and client each play in one
direction. The servers and clients add framing.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Final

from gatewaylab.od.aborts import SdoAbort, SdoAbortCode
from gatewaylab.od.crc import crc16_ccitt

__all__ = [
    "BLOCK_END",
    "CS_ABORT",
    "CS_BLOCK_ACK",
    "CS_BLOCK_DOWNLOAD_INITIATE_RESPONSE",
    "CS_BLOCK_END_RESPONSE",
    "CS_BLOCK_UPLOAD_START",
    "CS_DOWNLOAD_RESPONSE",
    "CS_UPLOAD_REQUEST",
    "CS_UPLOAD_SEGMENTED_RESPONSE",
    "SDO_HEADER",
    "SDO_HEADER_U32",
    "SEGMENT_DATA",
    "BlockReceiver",
    "BlockSender",
    "BlockUploadSub",
    "ClientCommand",
    "ClientSegmentedDownload",
    "ClientSegmentedUpload",
    "SegmentedDownload",
    "SegmentedUpload",
    "ServerCommand",
    "abort",
    "block_ack",
    "block_end",
    "block_segment",
    "check_size",
    "command",
    "download_response",
    "expedited_download_request",
    "expedited_size",
    "expedited_upload_response",
    "segment",
    "segment_ack",
    "segment_data",
]


#: command byte, index, subindex (CiA 301 figure 20 ff.)
SDO_HEADER: Final = struct.Struct("<BHB")
#: command byte, index, subindex, data word / size
SDO_HEADER_U32: Final = struct.Struct("<BHBI")
#: block end: command byte, CRC, 5 reserved bytes
BLOCK_END: Final = struct.Struct("<BH5x")
#: Data bytes in one CAN segment.
SEGMENT_DATA: Final = 7
#: Byte strings built once (immutable, so shared): a command byte alone, a command byte with 7
#: zero bytes (acknowledges), n zero bytes (padding). Compiled, an index into a tuple of constants
#: costs a few ns where ``bytes((cs, 0, ...))`` builds and converts a tuple (~250 ns).
_COMMAND_BYTE: Final = tuple(bytes((cs,)) for cs in range(256))
_ACK: Final = tuple(bytes((cs, 0, 0, 0, 0, 0, 0, 0)) for cs in range(256))
_ZEROS: Final = tuple(bytes(n) for n in range(SEGMENT_DATA + 1))


class ClientCommand(IntEnum):
    """Client command specifier (ccs, bits 7..5 of a request)."""

    DOWNLOAD_SEGMENT = 0
    INITIATE_DOWNLOAD = 1
    INITIATE_UPLOAD = 2
    UPLOAD_SEGMENT = 3
    ABORT = 4
    BLOCK_UPLOAD = 5
    BLOCK_DOWNLOAD = 6


class ServerCommand(IntEnum):
    """Server command specifier (scs, bits 7..5 of a response)."""

    UPLOAD_SEGMENT = 0
    DOWNLOAD_SEGMENT = 1
    INITIATE_UPLOAD = 2
    INITIATE_DOWNLOAD = 3
    ABORT = 4
    BLOCK_DOWNLOAD = 5
    BLOCK_UPLOAD = 6


class BlockUploadSub(IntEnum):
    """Client subcommand of a block upload request (cs bits 1..0)."""

    INITIATE = 0
    END = 1
    ACK = 2
    START = 3


#: Frequently sent command bytes.
CS_ABORT: Final = 0x80
CS_DOWNLOAD_RESPONSE: Final = 0x60           # scs 3: initiate download response
CS_UPLOAD_REQUEST: Final = 0x40              # ccs 2: initiate upload request
CS_UPLOAD_SEGMENTED_RESPONSE: Final = 0x41   # scs 2, size indicated, not expedited
CS_BLOCK_DOWNLOAD_INITIATE_RESPONSE: Final = 0xA4
CS_BLOCK_ACK: Final = 0xA2
CS_BLOCK_END_RESPONSE: Final = 0xA1
CS_BLOCK_UPLOAD_START: Final = 0xA3


def command(cs: int) -> int:
    """The command specifier (bits 7..5) of a command byte."""
    return cs >> 5


def abort(index: int, subindex: int, code: int) -> bytes:
    """An abort transfer request/response (8 bytes)."""
    return SDO_HEADER_U32.pack(CS_ABORT, index, subindex, code)


def expedited_size(cs: int) -> int | None:
    """Data bytes of an expedited initiate (None when the size is not indicated)."""
    return 4 - ((cs >> 2) & 0x03) if cs & 0x01 else None


def expedited_upload_response(index: int, subindex: int, value: bytes) -> bytes:
    """Initiate upload response carrying 1..4 bytes (scs 2, e = s = 1)."""
    n = 4 - len(value)
    return SDO_HEADER.pack(0x43 | (n << 2), index, subindex) + value + bytes(n)


def expedited_download_request(index: int, subindex: int, data: bytes, size_indicated: bool = True) -> bytes:
    """Initiate download request carrying 1..4 bytes (ccs 1, e = 1)."""
    n = 4 - len(data)
    cs = 0x23 | (n << 2) if size_indicated else 0x22
    return SDO_HEADER.pack(cs, index, subindex) + data + bytes(n)


def download_response(index: int, subindex: int) -> bytes:
    """Initiate download response (scs 3)."""
    return SDO_HEADER_U32.pack(CS_DOWNLOAD_RESPONSE, index, subindex, 0)


def segment(base: int, toggle: int, chunk: bytes, last: bool) -> bytes:
    """One segment: ``base`` (0x00 request / response cs), toggle bit, unused count n, c bit, data
    padded to 7 bytes (CoE segments may carry more; n is 0 then)."""
    n = SEGMENT_DATA - len(chunk) if len(chunk) < SEGMENT_DATA else 0
    return _COMMAND_BYTE[base | (toggle << 4) | (n << 1) | (1 if last else 0)] + chunk + _ZEROS[n]


def segment_ack(base: int, toggle: int) -> bytes:
    """A segment acknowledge: download segment response (0x20) or upload segment request (0x60)."""
    return _ACK[base | (toggle << 4)]


def segment_data(data: bytes) -> bytes:
    """The data of a received segment (8 bytes on CAN with n unused; longer on CoE): a slice of
    ``data`` (every caller appends it to a buffer; ``bytes()`` of a slice costs ~200 ns compiled)."""
    if len(data) > 8:
        return data[1:]
    return data[1:8 - ((data[0] >> 1) & 0x07)]


def block_segment(seq: int, chunk: bytes, last: bool) -> bytes:
    """One block-transfer segment: c bit, sequence number 1..127, 7 data bytes."""
    return _COMMAND_BYTE[(0x80 if last else 0) | seq] + chunk + _ZEROS[SEGMENT_DATA - len(chunk)]


def block_ack(ackseq: int, blksize: int) -> bytes:
    """Block acknowledge (sub-block received up to ``ackseq``, next block size)."""
    return bytes((CS_BLOCK_ACK, ackseq, blksize, 0, 0, 0, 0, 0))


def block_end(base: int, total: int, crc: int) -> bytes:
    """End block request/response: n bytes of the last segment unused, CRC."""
    used = total - SEGMENT_DATA * ((total - 1) // SEGMENT_DATA) if total else 0
    return BLOCK_END.pack(base | ((SEGMENT_DATA - used) << 2), crc)


def check_size(received: int, announced: int | None) -> None:
    """Transfers that end with another size than announced: 0x06070013 too low, else 0x06070010."""
    if announced is not None and received != announced:
        raise SdoAbort(SdoAbortCode.LENGTH_TOO_LOW if received < announced else SdoAbortCode.LENGTH_MISMATCH)


@dataclass(slots=True, init=False)
class SegmentedDownload:
    """A segmented download in progress: toggle check, collected data, announced size.

    Its ``__init__`` is written out: compiled, the one dataclasses generates is Python code run
    through the type (one per transfer, ~0.5 us); a native one stores the fields directly."""

    index: int
    subindex: int
    size: int | None
    limit: int
    #: Abort code when more than ``limit`` bytes arrive (CANopen: out of memory; CoE: too high).
    over: SdoAbortCode
    toggle: int
    buf: bytearray

    def __init__(self, index: int, subindex: int, size: int | None, limit: int,
                 over: SdoAbortCode = SdoAbortCode.OUT_OF_MEMORY, toggle: int = 0,
                 buf: bytearray | None = None) -> None:
        self.index = index
        self.subindex = subindex
        self.size = size
        self.limit = limit
        self.over = over
        self.toggle = toggle
        self.buf = bytearray() if buf is None else buf

    def segment(self, data: bytes) -> tuple[int, bool]:
        """Take one download segment; (toggle of the segment, last?). SdoAbort on a toggle error
        or on more data than ``limit``."""
        cs = data[0]
        toggle = (cs >> 4) & 1
        if toggle != self.toggle:
            raise SdoAbort(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED)
        self.buf += segment_data(data)
        if len(self.buf) > self.limit:
            raise SdoAbort(self.over)
        self.toggle ^= 1
        return toggle, bool(cs & 0x01)


@dataclass(slots=True, init=False)
class SegmentedUpload:
    """A segmented upload in progress: toggle check, the data still to send (``__init__`` written
    out, as in :class:`SegmentedDownload`)."""

    index: int
    subindex: int
    data: bytes
    max_segment: int
    pos: int
    toggle: int

    def __init__(self, index: int, subindex: int, data: bytes, max_segment: int = SEGMENT_DATA,
                 pos: int = 0, toggle: int = 0) -> None:
        self.index = index
        self.subindex = subindex
        self.data = data
        self.max_segment = max_segment
        self.pos = pos
        self.toggle = toggle

    def segment(self, cs: int) -> tuple[bytes, bool]:
        """Answer one upload segment request: (upload segment response, last?)."""
        toggle = (cs >> 4) & 1
        if toggle != self.toggle:
            raise SdoAbort(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED)
        pos = self.pos
        chunk = self.data[pos:pos + self.max_segment]
        self.pos = pos + len(chunk)
        last = self.pos >= len(self.data)
        self.toggle ^= 1
        return segment(0x00, toggle, chunk, last), last


@dataclass(slots=True)
class ClientSegmentedUpload:
    """The client's half of a segmented upload (CiA 301 7.2.4.3.5/7.2.4.3.6): the segment request
    to send next, the toggle it expects back, the data collected, the announced size checked."""

    size: int | None
    buf: bytearray = field(default_factory=bytearray)
    toggle: int = 0
    done: bool = False

    def __post_init__(self) -> None:
        # CoE: the initiate response may already carry everything announced
        if self.size is not None and len(self.buf) >= self.size:
            self.done = True

    def request(self) -> bytes:
        """The upload segment request for the segment expected next."""
        return segment_ack(ClientCommand.UPLOAD_SEGMENT << 5, self.toggle)

    def response(self, data: bytes) -> bool:
        """Take one upload segment response; True when it was the last. SdoAbort on a wrong
        command specifier (0x05040001), toggle (0x05030000) or total size (0x06070010)."""
        cs = data[0]
        if cs >> 5 != ServerCommand.UPLOAD_SEGMENT:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "not an upload segment response")
        if (cs >> 4) & 1 != self.toggle:
            raise SdoAbort(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED, "toggle bit in segment response")
        self.buf += segment_data(data)
        self.toggle ^= 1
        if cs & 0x01:
            if self.size is not None and len(self.buf) != self.size:
                raise SdoAbort(SdoAbortCode.LENGTH_MISMATCH, f"{len(self.buf)} bytes, {self.size} announced")
            self.done = True
        return self.done

    @property
    def data(self) -> bytes:
        """The data received so far (all of it once ``done``)."""
        return bytes(self.buf)


@dataclass(slots=True)
class ClientSegmentedDownload:
    """The client's half of a segmented download (CiA 301 7.2.4.3.3/7.2.4.3.4): the data cut
    into segments of ``max_segment`` bytes (7 on CAN, more in a CoE mailbox), the toggle checked in
    every download segment response."""

    data: bytes
    max_segment: int = SEGMENT_DATA
    pos: int = 0
    toggle: int = 0

    @property
    def done(self) -> bool:
        """Every segment was sent."""
        return self.pos >= len(self.data)

    def next_segment(self) -> bytes:
        """The next download segment request (the c bit set on the last one)."""
        chunk = self.data[self.pos:self.pos + self.max_segment]
        self.pos += len(chunk)
        return segment(ClientCommand.DOWNLOAD_SEGMENT << 5, self.toggle, chunk, self.done)

    def response(self, data: bytes) -> None:
        """Check one download segment response (scs 1 with the toggle of the segment it answers)."""
        cs = data[0]
        if cs & 0xEF != ServerCommand.DOWNLOAD_SEGMENT << 5:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "not a download segment response")
        if (cs >> 4) & 1 != self.toggle:
            raise SdoAbort(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED, "toggle bit in segment response")
        self.toggle ^= 1


@dataclass(slots=True)
class BlockSender:
    """The sending half of a block transfer (CiA 301 7.2.4.3.9-7.2.4.3.16): the client in a block
    download, the server in a block upload. Sends sub-blocks of up to ``blksize`` segments and
    rewinds to what the receiver's block acknowledge confirms, so lost segments are sent again."""

    data: bytes
    blksize: int = 127
    pos: int = 0
    block_start: int = 0
    sent: int = 0
    last_sent: bool = False

    def sub_block(self) -> list[bytes]:
        """The segments of the next sub-block, from the first byte not yet acknowledged."""
        data = self.data
        pos = self.block_start = self.pos
        total = len(data)
        frames: list[bytes] = []
        seq = 0
        last = False
        while seq < self.blksize and not last:
            seq += 1
            chunk = data[pos:pos + SEGMENT_DATA]
            pos += SEGMENT_DATA
            last = pos >= total
            frames.append(block_segment(seq, chunk, last))
        self.sent = seq
        self.last_sent = last
        return frames

    def ack(self, data: bytes) -> bool:
        """Take a block acknowledge (ackseq, next blksize); True when every segment is confirmed and
        the end frame comes next. SdoAbort on an ackseq beyond the segments sent (0x05040003) or a
        block size outside 1..127 (0x05040002)."""
        ackseq, blksize = data[1], data[2]
        if ackseq > self.sent:
            raise SdoAbort(SdoAbortCode.INVALID_SEQUENCE_NUMBER)
        if not 1 <= blksize <= 127:
            raise SdoAbort(SdoAbortCode.INVALID_BLOCK_SIZE)
        self.blksize = blksize
        self.pos = min(self.block_start + SEGMENT_DATA * ackseq, len(self.data))
        return self.last_sent and ackseq == self.sent

    def end(self, crc: bool) -> bytes:
        """The end block request/response (cs 0xC1): unused bytes of the last segment, CRC or 0."""
        return block_end(0xC1, len(self.data), crc16_ccitt(self.data) if crc else 0)


@dataclass(slots=True)
class BlockReceiver:
    """The receiving half of a block transfer (CiA 301 7.2.4.3.9-7.2.4.3.16): the server in a block
    download, the client in a block upload. Keeps the segments that arrive in sequence and
    acknowledges each sub-block; a segment after a lost one is dropped, the sender repeats it."""

    blksize: int = 127
    ackseq: int = 0
    buf: bytearray = field(default_factory=bytearray)
    #: the segment with the c bit arrived in sequence: the end frame comes next
    last: bool = False

    def segment(self, data: bytes) -> bytes | None:
        """Take one block segment; the block acknowledge to send when the sub-block ends (segment
        ``blksize`` or one with the c bit), else None. SdoAbort 0x05040003 on sequence number 0 or
        beyond ``blksize``."""
        cs = data[0]
        seq = cs & 0x7F
        if seq == 0 or seq > self.blksize:
            raise SdoAbort(SdoAbortCode.INVALID_SEQUENCE_NUMBER)
        if seq == self.ackseq + 1:
            self.ackseq = seq
            self.buf += data[1:8]
            if cs & 0x80:
                self.last = True
        if seq == self.blksize or cs & 0x80:
            ackseq = self.ackseq
            self.ackseq = 0
            return block_ack(ackseq, self.blksize)
        return None

    def end(self, data: bytes, size: int | None, crc: bool,
            short: SdoAbortCode = SdoAbortCode.LENGTH_TOO_LOW) -> bytes:
        """The data of a finished transfer: the end frame's n unused bytes cut off, then the size
        checked against ``size`` (``short`` when fewer bytes came, 0x06070010 when more) and the
        CRC when ``crc`` (0x05040004)."""
        n = (data[0] >> 2) & 0x07
        payload = bytes(self.buf[:len(self.buf) - n])
        if size is not None and len(payload) != size:
            raise SdoAbort(short if len(payload) < size else SdoAbortCode.LENGTH_MISMATCH)
        if crc and crc16_ccitt(payload) != BLOCK_END.unpack_from(data)[1]:
            raise SdoAbort(SdoAbortCode.CRC_ERROR)
        return payload
