"""The records of a frame-stream image (manual chapters 6, 8, 10): the fixed header, the two packet
kinds and a parsed image. Frozen values; a packet is checked once when it is made, and carries
its control word and its bytes on the wire (8.1, 8.3), so encoding joins them.

A :class:`CanPacket` holds a :class:`~gatewaylab.bus.frame.CanFrame` (the CAN rules are the
frame's); the packet adds what the stream carries beside it: the channel, the timestamp field
or the scheduled-transmit reservation (8.4), ID_AUX and the D64 window (8.1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gatewaylab.bus.frame import MAX_EXT_ID, MAX_STD_ID, CanFrame
from gatewaylab.common.errors import FrameError
from gatewaylab.devices.ecanlite.stream.format import (
    CRC_ALG_CCITT_FALSE,
    HEADER,
    HEADER_SIZE,
    NO_FLAGS,
    PACKET_HEADS,
    TSF_BYTES,
    TSFS,
    TX_RESULT,
    VER_IHL,
    ZERO_PAD,
    HeaderFlags,
    PacketKind,
    ParseDiag,
    PdoError,
    StreamEncodeError,
    StreamError,
    Tsf,
    TxResultCode,
)

__all__ = ["RESULT_VALUES", "CanPacket", "DecodedStream", "Packet", "StreamHeader", "TxResultPacket", "refuse"]


def refuse(code: PdoError, message: str) -> StreamEncodeError:
    """The error for a packet no receiver would take, with the LastPDOError it would report."""
    return StreamEncodeError(code, message)


def _ints(*values: object) -> bool:
    """All ``values`` are integers: the check of arguments typed ``int`` that a caller may still get
    wrong (an ``isinstance`` of a name typed ``int`` is unreachable to mypy, and mypyc mistranslates
    the error branch under it)."""
    return all(isinstance(v, int) for v in values)


def _bytes_like(data: object) -> bool:
    """``data`` is bytes, a bytearray or a memoryview (see :func:`_ints`)."""
    return isinstance(data, (bytes, bytearray, memoryview))


@dataclass(frozen=True, slots=True)
class StreamHeader:
    """The 24-byte fixed header (chapter 6), field by field."""

    header_flags: HeaderFlags = NO_FLAGS
    seq_begin: int = 0
    seq_end: int = 0
    payload_len: int = 0
    payload_crc16: int = 0
    layout_id: int = 0
    channel_mask: int = 0
    frame_count: int = 0
    overflow_sat: int = 0
    crc_alg: int = CRC_ALG_CCITT_FALSE
    channel_status: tuple[int, int, int, int] = (0, 0, 0, 0)
    ver_ihl: int = VER_IHL

    def __init__(self, header_flags: HeaderFlags = NO_FLAGS, seq_begin: int = 0, seq_end: int = 0, payload_len: int = 0,
                 payload_crc16: int = 0, layout_id: int = 0, channel_mask: int = 0, frame_count: int = 0,
                 overflow_sat: int = 0, crc_alg: int = CRC_ALG_CCITT_FALSE,
                 channel_status: tuple[int, int, int, int] = (0, 0, 0, 0), ver_ihl: int = VER_IHL) -> None:
        # Written out like CanPacket's (compiled, a dataclass-made __init__ is an interpreted call
        # through an argument tuple: ~2 us per decoded image).
        object.__setattr__(self, "header_flags", header_flags)
        object.__setattr__(self, "seq_begin", seq_begin)
        object.__setattr__(self, "seq_end", seq_end)
        object.__setattr__(self, "payload_len", payload_len)
        object.__setattr__(self, "payload_crc16", payload_crc16)
        object.__setattr__(self, "layout_id", layout_id)
        object.__setattr__(self, "channel_mask", channel_mask)
        object.__setattr__(self, "frame_count", frame_count)
        object.__setattr__(self, "overflow_sat", overflow_sat)
        object.__setattr__(self, "crc_alg", crc_alg)
        object.__setattr__(self, "channel_status", channel_status)
        object.__setattr__(self, "ver_ihl", ver_ihl)

    def __reduce__(self) -> tuple[type[StreamHeader], tuple[HeaderFlags, int, int, int, int, int, int, int, int, int,
                                                            tuple[int, int, int, int], int]]:
        # Pickled and copied by its constructor (see CanPacket.__reduce__).
        return StreamHeader, (self.header_flags, self.seq_begin, self.seq_end, self.payload_len, self.payload_crc16,
                              self.layout_id, self.channel_mask, self.frame_count, self.overflow_sat, self.crc_alg,
                              self.channel_status, self.ver_ihl)

    @property
    def crc(self) -> int:
        """payload_crc16 (the name parse_diag uses, 16.2)."""
        return self.payload_crc16

    @property
    def version(self) -> int:
        """Header version (high nibble of ver_ihl): 1."""
        return self.ver_ihl >> 4

    @property
    def ihl(self) -> int:
        """Header length in 4-byte words (low nibble of ver_ihl): 6."""
        return self.ver_ihl & 0x0F

    @property
    def committed(self) -> bool:
        """seq_begin == seq_end: the sender finished this image (6.1)."""
        return self.seq_begin == self.seq_end

    @property
    def incomplete(self) -> bool:
        """overflow_sat != 0 or STREAM_TRUNCATED: frames were left out of this cycle (6.1 step 8)."""
        return self.overflow_sat != 0 or bool(self.header_flags & HeaderFlags.STREAM_TRUNCATED)

    def pack(self) -> bytes:
        """The 24 header bytes."""
        return HEADER.pack(self.ver_ihl, self.header_flags, self.seq_begin, self.seq_end, self.payload_len,
                            self.payload_crc16, self.layout_id, self.channel_mask, self.frame_count,
                            self.overflow_sat, self.crc_alg, *self.channel_status)

    @classmethod
    def unpack(cls, image: bytes | bytearray | memoryview) -> StreamHeader:
        """The header of an image; an image shorter than 24 bytes is StreamError ACTIVE_AREA."""
        if len(image) < HEADER_SIZE:
            raise StreamError(PdoError.ACTIVE_AREA, ParseDiag(reason=f"image of {len(image)} bytes has no header"))
        (ver_ihl, flags, seq_begin, seq_end, payload_len, crc, layout_id, mask, count, overflow, crc_alg,
         s0, s1, s2, s3) = HEADER.unpack_from(image, 0)
        return cls(HeaderFlags(flags & 0x3F), seq_begin, seq_end, payload_len, crc, layout_id, mask, count,
                   overflow, crc_alg, (s0, s1, s2, s3), ver_ihl)


@dataclass(frozen=True, slots=True)
class CanPacket:
    """A CAN_FRAME packet (8.1): one CAN / CAN FD frame of a channel, checked once when built.

    ``timestamp`` is the raw delta16/delta32/full64 value in :data:`TIMESTAMP_UNIT_S` ticks
    (TxPDO). In the RxPDO, ``tsf=FULL64`` with ``scheduled`` is the SYNC0 reservation of 8.4/13.8:
    ``offset_ns`` after the next SYNC0, ``tag`` the master's own 16 bits. ``d64`` sends the data
    in a fixed 64-byte window (profiles 4/5). ``id_aux`` is ID_AUX (8.1). :meth:`of` builds one
    from the frame's fields. A packet no layout can carry raises :class:`StreamEncodeError` with
    the LastPDOError a receiver would report; what a particular layout allows is checked on
    encoding.
    """

    channel: int
    frame: CanFrame
    tsf: Tsf = Tsf.NONE
    timestamp: int = 0
    scheduled: bool = False
    offset_ns: int = 0
    tag: int = 0
    id_aux: int = 0
    d64: bool = False
    #: The control word (KIND 0, chapter 8), derived from the fields.
    ctrl: int = field(init=False, repr=False, compare=False, default=0)
    #: The packet's bytes on the wire (8.1, 8.3 without ALIGN4 padding), derived from the fields.
    wire: bytes = field(init=False, repr=False, compare=False, default=b"")

    def __init__(self, channel: int, frame: CanFrame, tsf: Tsf = Tsf.NONE, timestamp: int = 0,
                 scheduled: bool = False, offset_ns: int = 0, tag: int = 0, id_aux: int = 0, d64: bool = False,
                 *, ctrl: int = -1, wire: bytes = b"") -> None:
        # Written out (dataclass keeps an explicit __init__), fields stored with object.__setattr__:
        # compiled (mypyc), each is a direct store into the native object. Given ``ctrl`` and ``wire``
        # (only the decoder, :mod:`.decode`: it checked the control word, the frame checked itself), the
        # fields are stored as they are; else __post_init__ checks and derives them.
        object.__setattr__(self, "channel", channel)
        object.__setattr__(self, "frame", frame)
        object.__setattr__(self, "tsf", tsf)
        object.__setattr__(self, "timestamp", timestamp)
        object.__setattr__(self, "scheduled", scheduled)
        object.__setattr__(self, "offset_ns", offset_ns)
        object.__setattr__(self, "tag", tag)
        object.__setattr__(self, "id_aux", id_aux)
        object.__setattr__(self, "d64", d64)
        if ctrl < 0:
            self.__post_init__()
            return
        object.__setattr__(self, "ctrl", ctrl)
        object.__setattr__(self, "wire", wire)

    def __post_init__(self) -> None:
        frame, channel, tsf = self.frame, self.channel, self.tsf
        if type(frame) is not CanFrame:
            raise refuse(PdoError.INVALID_DLC, f"a CAN_FRAME carries a CanFrame, got {type(frame).__name__}")
        if type(channel) is not int or not 0 <= channel <= 7:
            raise refuse(PdoError.INVALID_CHANNEL, f"channel {channel!r} does not fit CH (0..7, chapter 8)")
        timestamp, offset_ns, tag, id_aux = self.timestamp, self.offset_ns, self.tag, self.id_aux
        if not _ints(timestamp, offset_ns, tag, id_aux):
            raise refuse(PdoError.RESERVED_BIT, "timestamp, offset_ns, tag, ID_AUX are integers: "
                                                f"{(timestamp, offset_ns, tag, id_aux)!r}")
        if self.d64 and not frame.fd:
            raise refuse(PdoError.INVALID_DLC, "D64 needs CAN FD (8.2)")
        if type(tsf) is not Tsf:
            if tsf not in (0, 1, 2, 3):
                raise refuse(PdoError.INVALID_TSF, f"TSF {tsf!r} is not 0..3 (8.4)")
            tsf = TSFS[tsf]
            object.__setattr__(self, "tsf", tsf)
        if self.scheduled:
            if tsf is not Tsf.FULL64:
                raise refuse(PdoError.BAD_SCHEDULE, "scheduled transmit is TSF_FULL64 format 1 (8.4)")
            if not 0 <= offset_ns <= 0xFFFFFFFF or not 0 <= tag <= 0xFFFF or timestamp:
                raise refuse(PdoError.BAD_SCHEDULE, "offset_ns is u32, tag u16, no timestamp (8.4)")
        elif offset_ns or tag:
            raise refuse(PdoError.BAD_SCHEDULE, "offset_ns and tag belong to scheduled packets (8.4)")
        elif not 0 <= timestamp < 1 << (8 * TSF_BYTES[tsf]):
            raise refuse(PdoError.INVALID_TSF, f"timestamp {timestamp} does not fit TSF {tsf} (8.4)")
        if not 0 <= id_aux <= 7:
            raise refuse(PdoError.RESERVED_BIT, f"ID_AUX {id_aux} out of range (8.1)")
        fd = frame.fd
        ide = 1 if frame.extended else 0
        x = frame.esi if fd else frame.rtr
        ctrl = (channel | frame.dlc << 3 | ide << 7 | fd << 8 | frame.brs << 9 | x << 10 | tsf << 11
                | bool(self.d64) << 15)
        ident = frame.can_id | id_aux << (29 if ide else 11)
        if self.scheduled:
            wire = PACKET_HEADS[ide][4].pack(ctrl, ident, 1, 0, tag, offset_ns)
        elif tsf:
            wire = PACKET_HEADS[ide][tsf].pack(ctrl, ident, timestamp)
        else:
            wire = PACKET_HEADS[ide][0].pack(ctrl, ident)
        data = frame.data
        object.__setattr__(self, "ctrl", ctrl)
        object.__setattr__(self, "wire", wire + data + ZERO_PAD[:64 - len(data)] if self.d64 else wire + data)

    def __reduce__(self) -> tuple[type[CanPacket], tuple[int, CanFrame, Tsf, int, bool, int, int, int, bool]]:
        # Pickled by its constructor: compiled (mypyc), the default pickling refills a frozen object
        # through setattr and fails.
        return CanPacket, (self.channel, self.frame, self.tsf, self.timestamp, self.scheduled, self.offset_ns,
                           self.tag, self.id_aux, self.d64)

    @classmethod
    def of(cls, channel: int, can_id: int, extended: bool = False, fd: bool = False, brs: bool = False,
           rtr: bool = False, esi: bool = False, data: bytes = b"", tsf: Tsf = Tsf.NONE, timestamp: int = 0,
           scheduled: bool = False, offset_ns: int = 0, tag: int = 0, id_aux: int = 0, d64: bool = False,
           dlc: int = -1) -> CanPacket:
        """The packet of a frame given field by field; ``dlc`` is the DLC field (8.2): give it for
        classic remote frames (no data, DLC = requested length), else -1 derives it from ``data``.
        A frame CAN cannot carry is refused with INVALID_DLC (RESERVED_BIT for an identifier out
        of range, 8.1)."""
        if not _bytes_like(data):
            raise refuse(PdoError.INVALID_DLC, f"data must be bytes, got {type(data).__name__}")
        if type(channel) is not int or not 0 <= channel <= 7:
            raise refuse(PdoError.INVALID_CHANNEL, f"channel {channel!r} does not fit CH (0..7, chapter 8)")
        if not _ints(can_id, dlc):
            raise refuse(PdoError.RESERVED_BIT, f"id and DLC are integers: {(can_id, dlc)!r}")
        if d64 and not fd:
            raise refuse(PdoError.INVALID_DLC, "D64 needs CAN FD (8.2)")
        try:
            frame = CanFrame(can_id, bytes(data), extended, rtr, fd, brs, esi, dlc)
        except FrameError as exc:
            code = (PdoError.INVALID_DLC if 0 <= can_id <= (MAX_EXT_ID if extended else MAX_STD_ID)
                    else PdoError.RESERVED_BIT)
            raise refuse(code, f"{exc} (8.1, 8.2)") from None
        return cls(channel, frame, tsf, timestamp, scheduled, offset_ns, tag, id_aux, d64)

    @classmethod
    def from_frame(cls, channel: int, frame: CanFrame, *, tsf: Tsf = Tsf.NONE, timestamp: int = 0,
                   id_aux: int = 0, d64: bool = False) -> CanPacket:
        """The packet carrying a bus frame received on ``channel`` (TxPDO direction)."""
        return cls(channel, frame, tsf, timestamp, False, 0, 0, id_aux, d64)

    @classmethod
    def classic(cls, channel: int, can_id: int, data: bytes = b"", *, tsf: Tsf = Tsf.NONE,
                timestamp: int = 0) -> CanPacket:
        """A classic 11-bit data frame, the packet of almost every cycle (the MCAN Port's
        ``send_can``)."""
        return cls.of(channel, can_id, data=data, tsf=tsf, timestamp=timestamp)

    @property
    def kind(self) -> PacketKind:
        """KIND 0."""
        return PacketKind.CAN_FRAME

    @property
    def can_id(self) -> int:
        """The frame's identifier."""
        return self.frame.can_id

    @property
    def extended(self) -> bool:
        """IDE: a 29-bit identifier."""
        return self.frame.extended

    @property
    def fd(self) -> bool:
        """FDF: a CAN FD frame."""
        return self.frame.fd

    @property
    def brs(self) -> bool:
        """BRS: the data phase at the data bit rate."""
        return self.frame.brs

    @property
    def rtr(self) -> bool:
        """A classic remote frame."""
        return self.frame.rtr

    @property
    def esi(self) -> bool:
        """ESI: the sender was error passive."""
        return self.frame.esi

    @property
    def data(self) -> bytes:
        """The frame's data bytes."""
        return self.frame.data

    @property
    def dlc(self) -> int:
        """The DLC field (8.2)."""
        return self.frame.dlc

    @property
    def raw_size(self) -> int:
        """raw_packet_bytes: the packet without ALIGN4 padding (8.3)."""
        return len(self.wire)


@dataclass(frozen=True, slots=True)
class TxResultPacket:
    """A TX_RESULT packet (chapter 10): the outcome of frame ``ref_frame_index`` (counting KIND 0
    packets from 0) of the RxPDO image committed with sequence ``ref_packet_seq``."""

    channel: int
    ref_packet_seq: int
    ref_frame_index: int
    result: TxResultCode
    #: The control word (CH and KIND 1, chapter 10), derived from the channel.
    ctrl: int = field(init=False, repr=False, compare=False, default=0)
    #: The 6 bytes on the wire, derived from the fields.
    wire: bytes = field(init=False, repr=False, compare=False, default=b"")

    def __init__(self, channel: int, ref_packet_seq: int, ref_frame_index: int, result: TxResultCode) -> None:
        # Written out (see StreamHeader.__init__), then checked and derived by __post_init__.
        object.__setattr__(self, "channel", channel)
        object.__setattr__(self, "ref_packet_seq", ref_packet_seq)
        object.__setattr__(self, "ref_frame_index", ref_frame_index)
        object.__setattr__(self, "result", result)
        self.__post_init__()

    def __post_init__(self) -> None:
        channel, seq, index, result = self.channel, self.ref_packet_seq, self.ref_frame_index, self.result
        if type(channel) is not int or not 0 <= channel <= 7:
            raise refuse(PdoError.INVALID_CHANNEL, f"channel {channel!r} does not fit CH (0..7, chapter 8)")
        if not _ints(seq, index) or not 0 <= seq <= 0xFFFF or not 0 <= index <= 0xFF:
            raise refuse(PdoError.UNKNOWN_KIND, "RefPacketSeq is u16, RefFrameIndex u8 (10)")
        if type(result) is not TxResultCode:
            if result not in RESULT_VALUES:
                raise refuse(PdoError.UNKNOWN_KIND, f"ResultCode {result!r} is not 0..5 (10)")
            result = TxResultCode(result)
            object.__setattr__(self, "result", result)
        ctrl = channel | 1 << 13
        object.__setattr__(self, "ctrl", ctrl)
        object.__setattr__(self, "wire", TX_RESULT.pack(ctrl, seq, index, result))

    def __reduce__(self) -> tuple[type[TxResultPacket], tuple[int, int, int, TxResultCode]]:
        # Pickled by its constructor (see CanPacket.__reduce__).
        return TxResultPacket, (self.channel, self.ref_packet_seq, self.ref_frame_index, self.result)

    @property
    def kind(self) -> PacketKind:
        """KIND 1."""
        return PacketKind.TX_RESULT


Packet = CanPacket | TxResultPacket
RESULT_VALUES = frozenset(range(6))


@dataclass(frozen=True, slots=True)
class DecodedStream:
    """A parsed image: its header and packets in stream order."""

    header: StreamHeader
    packets: tuple[Packet, ...]

    def __init__(self, header: StreamHeader, packets: tuple[Packet, ...]) -> None:
        # Written out (see StreamHeader.__init__).
        object.__setattr__(self, "header", header)
        object.__setattr__(self, "packets", packets)

    def __reduce__(self) -> tuple[type[DecodedStream], tuple[StreamHeader, tuple[Packet, ...]]]:
        # Pickled and copied by its constructor (see CanPacket.__reduce__).
        return DecodedStream, (self.header, self.packets)

    @property
    def frames(self) -> tuple[CanPacket, ...]:
        """The CAN_FRAME packets; index i is RefFrameIndex i (chapter 10)."""
        return tuple(p for p in self.packets if type(p) is CanPacket)

    @property
    def tx_results(self) -> tuple[TxResultPacket, ...]:
        """The TX_RESULT packets."""
        return tuple(p for p in self.packets if type(p) is TxResultPacket)

    @property
    def seq(self) -> int:
        """The committed sequence (seq_begin == seq_end)."""
        return self.header.seq_begin

