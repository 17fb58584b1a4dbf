"""The cannelloni UDP format (mguentner/cannelloni doc/udp_format.md, parser.cpp), sans-I/O.

A datagram: a 5-byte header ``version (2), op code (0 = DATA), seq_no, count (big-endian u16)`` and
``count`` frames, each ``can_id`` (big-endian u32 with linux/can.h's EFF/RTR/ERR flags), ``len``
(bit 7 set: a CAN FD frame, followed by one ``flags`` byte, canfd_frame's BRS 0x01 / ESI 0x02) and
``len & 0x7F`` data bytes (none for remote frames, whose ``len`` is the DLC).

Like upstream (udpthread.cpp) the sender buffers frames and sends them when the buffer timeout
expires (``-t``, per-id timeouts of ``-T`` shorten it) or the next frame could not fit into the
link's payload (MTU - IP header - UDP header); sequence numbers count packets modulo 256, and
the receiver does not act on them (here they count missing packets). A packet whose version or op
code is wrong is dropped; frames before a corrupt one are delivered (parseFrames()), the rest is
dropped; bytes after the ``count`` frames are ignored.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from gatewaylab.bus.frame import FD_LEN_TO_DLC, CanFrame
from gatewaylab.common.errors import FrameError

__all__ = [
    "CANFD_BRS",
    "CANFD_ESI",
    "CANFD_FRAME",
    "CANFD_MAX_DLEN",
    "CAN_EFF_FLAG",
    "CAN_EFF_MASK",
    "CAN_ERR_FLAG",
    "CAN_RTR_FLAG",
    "CAN_SFF_MASK",
    "FRAME_HEAD",
    "HEADER",
    "IPV4_HEADER_SIZE",
    "IPV6_HEADER_SIZE",
    "OP_DATA",
    "UDP_HEADER_SIZE",
    "VERSION",
    "Packet",
    "Sender",
    "SeqTracker",
    "decode_packet",
    "encode_frame",
    "encode_packet",
    "frame_size",
]


HEADER = struct.Struct(">BBBH")
FRAME_HEAD = struct.Struct(">IB")
#: cannelloni.h CANNELLONI_FRAME_VERSION and op_codes
VERSION = 2
OP_DATA = 0
#: cannelloni.h CANFD_FRAME: the MSB of ``len`` marks a CAN FD frame
CANFD_FRAME = 0x80
#: linux/can.h
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
CAN_SFF_MASK = 0x7FF
CANFD_BRS = 0x01
CANFD_ESI = 0x02
CANFD_MAX_DLEN = 64
#: udpthread.cpp: IPv4 / IPv6 and UDP header sizes subtracted from the link MTU
IPV4_HEADER_SIZE = 20
IPV6_HEADER_SIZE = 40
UDP_HEADER_SIZE = 8


def encode_frame(frame: CanFrame) -> bytes:
    """parser.cpp encodeFrame(): one frame of a DATA packet."""
    can_id = frame.can_id | (CAN_EFF_FLAG if frame.extended else 0) | (CAN_RTR_FLAG if frame.rtr else 0)
    if frame.fd:
        flags = (CANFD_BRS if frame.brs else 0) | (CANFD_ESI if frame.esi else 0)
        return FRAME_HEAD.pack(can_id, len(frame.data) | CANFD_FRAME) + bytes((flags,)) + frame.data
    if frame.rtr:
        return FRAME_HEAD.pack(can_id, frame.dlc)
    return FRAME_HEAD.pack(can_id, len(frame.data)) + frame.data


def frame_size(frame: CanFrame) -> int:
    """Bytes :func:`encode_frame` makes of ``frame``."""
    return FRAME_HEAD.size + (1 if frame.fd else 0) + (0 if frame.rtr else len(frame.data))


def encode_packet(frames: list[CanFrame] | tuple[CanFrame, ...], seq_no: int) -> bytes:
    """parser.cpp buildPacket(): a DATA packet of ``frames`` (the caller keeps it under the payload size)."""
    return HEADER.pack(VERSION, OP_DATA, seq_no & 0xFF, len(frames)) + b"".join(encode_frame(f) for f in frames)


@dataclass(frozen=True, slots=True)
class Packet:
    """A decoded datagram: its sequence number, the frames delivered, and why the rest was dropped."""

    seq_no: int
    frames: tuple[CanFrame, ...]
    error: str | None = None
    #: frames that are no CAN data frame here (error frames, CAN_ERR_FLAG): not delivered
    skipped: int = 0


def decode_packet(data: bytes) -> Packet:
    """parser.cpp parseFrames(): never raises; a bad packet carries its error (and the frames before)."""
    if len(data) < HEADER.size:
        return Packet(-1, (), f"{len(data)} bytes: shorter than the {HEADER.size}-byte header")
    version, op_code, seq_no, count = HEADER.unpack_from(data)
    if version != VERSION:
        return Packet(seq_no, (), f"wrong version {version} (need {VERSION})")
    if op_code != OP_DATA:
        return Packet(seq_no, (), f"wrong op code {op_code} (DATA is {OP_DATA})")
    frames: list[CanFrame] = []
    skipped = 0
    pos = HEADER.size
    end = len(data)
    for i in range(count):
        if pos + FRAME_HEAD.size > end:
            return Packet(seq_no, tuple(frames), f"incomplete packet: frame {i + 1} of {count} missing", skipped)
        raw_id, raw_len = FRAME_HEAD.unpack_from(data, pos)
        pos += FRAME_HEAD.size
        length = raw_len & ~CANFD_FRAME
        if length > CANFD_MAX_DLEN:
            return Packet(seq_no, tuple(frames), f"frame {i + 1}: len {length} > {CANFD_MAX_DLEN}", skipped)
        fd = bool(raw_len & CANFD_FRAME)
        flags = 0
        if fd:
            if pos >= end:
                return Packet(seq_no, tuple(frames), f"frame {i + 1}: flags missing", skipped)
            flags = data[pos]
            pos += 1
        rtr = bool(raw_id & CAN_RTR_FLAG)
        payload = b""
        if not rtr:
            if pos + length > end:
                return Packet(seq_no, tuple(frames), f"incomplete packet: frame {i + 1} has {end - pos} of "
                                                     f"{length} data bytes", skipped)
            payload = data[pos:pos + length]
            pos += length
        if raw_id & CAN_ERR_FLAG:
            skipped += 1
            continue
        extended = bool(raw_id & CAN_EFF_FLAG)
        can_id = raw_id & (CAN_EFF_MASK if extended else CAN_SFF_MASK)
        try:
            if rtr:
                frame = CanFrame(can_id, b"", extended, rtr=True, dlc=length)
            elif fd:
                if length not in FD_LEN_TO_DLC:
                    raise FrameError(f"CAN FD len {length} matches no DLC")
                frame = CanFrame(can_id, payload, extended, fd=True, brs=bool(flags & CANFD_BRS),
                                 esi=bool(flags & CANFD_ESI))
            else:
                frame = CanFrame(can_id, payload, extended)
        except FrameError as exc:
            return Packet(seq_no, tuple(frames), f"frame {i + 1}: {exc}", skipped)
        frames.append(frame)
    return Packet(seq_no, tuple(frames), None, skipped)


@dataclass(slots=True)
class Sender:
    """udpthread.cpp transmitFrame()/prepareBuffer(): buffer frames, say when to send, build packets.

    :meth:`add` returns a packet when the buffer (with room for one more frame header) reaches the
    payload size, else the deadline (seconds after now) by which the buffer must go out: the buffer
    timeout, or a shorter per-id timeout. :meth:`packet` takes out as many frames as fit.
    """

    payload_size: int = 1500 - IPV4_HEADER_SIZE - UDP_HEADER_SIZE
    timeout: float = 0.1
    timeouts: dict[tuple[int, bool], float] = field(default_factory=dict)
    sort: bool = False
    seq_no: int = 0
    buffer: list[CanFrame] = field(default_factory=list)
    size: int = 0
    packets: int = 0

    def add(self, frame: CanFrame) -> float:
        """Buffer ``frame``; the time (from now) within which :meth:`packet` must be called (0: now)."""
        self.buffer.append(frame)
        self.size += frame_size(frame)
        if self.size + HEADER.size + FRAME_HEAD.size >= self.payload_size:
            return 0.0
        return min(self.timeout, self.timeouts.get((frame.can_id, frame.extended), self.timeout))

    def packet(self) -> bytes | None:
        """The next DATA packet (None when the buffer is empty); what does not fit stays buffered."""
        if not self.buffer:
            return None
        frames = sorted(self.buffer, key=lambda f: f.can_id) if self.sort else self.buffer
        size = HEADER.size
        n = 0
        for frame in frames:
            if size + frame_size(frame) > self.payload_size:
                break
            size += frame_size(frame)
            n += 1
        n = max(n, 1)   # a frame larger than the payload still goes (the IP layer fragments it)
        out, rest = frames[:n], frames[n:]
        self.buffer = list(rest)
        self.size = sum(frame_size(f) for f in rest)
        data = encode_packet(out, self.seq_no)
        self.seq_no = (self.seq_no + 1) & 0xFF
        self.packets += 1
        return data


@dataclass(slots=True)
class SeqTracker:
    """Counts packets that never came, from the gaps in the sequence numbers (upstream ignores them)."""

    expected: int | None = None
    missing: int = 0
    received: int = 0

    def seen(self, seq_no: int) -> None:
        """Count a received packet's sequence number; a jump counts the packets lost in between."""
        self.received += 1
        if self.expected is not None and seq_no != self.expected:
            gap = (seq_no - self.expected) & 0xFF
            if gap >= 128:           # late (reordered): counted missing before, it came after all
                self.missing = max(0, self.missing - 1)
                return
            self.missing += gap
        self.expected = (seq_no + 1) & 0xFF
