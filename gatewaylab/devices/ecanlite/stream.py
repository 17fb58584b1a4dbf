"""The ECAN-Lite frame-stream PDO codec (manual chapters 6-11, 13.2, 13.8): the one copy of the format.

Both PDO directions carry the same image of ``128*N`` bytes (5.2): a 24-byte little-endian fixed
header (chapter 6) and, from offset 24, a stream of packets (chapter 8): CAN_FRAME (KIND 0) and,
in the TxPDO only, TX_RESULT (KIND 1, chapter 10). The device parses the RxPDO and builds the
TxPDO with this module; the host library (issue 12) does the opposite with the same functions.

- :func:`encode_stream` / :func:`encode_into` build an image (packets, zeroed unused area, CRC,
  layout_id, header written last with seq_end == seq_begin, 5.4.4.1 step 4).
- :func:`commit_state` tells a new image from an idempotent repeat and from a torn one (6.1).
- :func:`decode_stream` checks header and packets in the order of 6.1 and raises
  :class:`StreamError` with the LastPDOError code of 13.2 and a parse diagnostic (16.2); it never
  raises anything else, whatever the bytes.
- :func:`packet_size` is the length a packet occupies (8.3, with ALIGN4), for the budget.

What a packet may carry depends on the active profile word of its direction (:class:`StreamLayout`,
chapter 9) and on the device's feature flags (0xF000:16, 13.8); choices the manual leaves open
are listed in docs/decisions.md under "ECAN-Lite frame stream (issue 10)".
"""

from __future__ import annotations

import binascii
import enum
import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from ...bus.frame import FD_DLC_TO_LEN, FD_LEN_TO_DLC, MAX_EXT_ID, MAX_STD_ID, CanFrame
from ...common.errors import LocalError, ProtocolError
from .budget import BudgetPolicy

__all__ = [
    "CRC_ALG_CCITT_FALSE", "DEFAULT_FEATURES", "HEADER_SIZE", "MAX_CHANNELS", "MAX_FRAME_COUNT",
    "OPTION_MASK", "PROFILE_MASK", "TIMESTAMP_UNIT_S", "VER_IHL",
    "ApplyStatus", "CanPacket", "Commit", "DecodedStream", "Direction", "Feature", "HeaderFlags",
    "Option", "Packet", "PacketKind", "ParseDiag", "PdoError", "StreamEncodeError", "StreamError",
    "StreamHeader", "StreamLayout", "Tsf", "TxResultCode", "TxResultPacket",
    "check_layout", "check_options", "commit_state", "crc16", "decode_stream", "dlc_to_len",
    "encode_into", "encode_stream", "fold_layout_id", "next_seq", "packet_size", "profile_word",
    "saturate_u8", "timestamp_ticks",
]

#: ver_ihl: version 1 in the high nibble, 6 four-byte words in the low nibble (chapter 6).
VER_IHL = 0x16
HEADER_SIZE = 24
#: crc_alg value for CRC-16/CCITT-FALSE (chapter 6); 0 with NO_CRC16_ENABLE (9.1).
CRC_ALG_CCITT_FALSE = 1
#: 0xF000:14 Max CAN channels.
MAX_CHANNELS = 4
#: frame_count is one byte (chapter 6).
MAX_FRAME_COUNT = 255
#: 0xF000:12 Encapsulation profile mask: profiles 0, 1, 4, 5.
PROFILE_MASK = 0x33
#: 0xF000:15 PDO option flags mask.
OPTION_MASK = 0x1F
#: One tick of delta16/delta32/full64 timestamps (8.4 gives no unit; docs/decisions.md).
TIMESTAMP_UNIT_S = 1e-6


class PdoError(enum.IntEnum):
    """LastPDOError, 0x8010/0x8011:14 (13.2 "Last PDO error common values"); 1 is not defined."""

    OK = 0
    FRAME_OVERRUN = 2
    PACKET_OVERRUN = 3
    UNKNOWN_KIND = 4
    INVALID_DLC = 5
    INVALID_CHANNEL = 6
    INVALID_TSF = 7
    TRUNCATED = 8
    UNSUPPORTED_PROFILE = 9
    DUPLICATE_SEQUENCE = 10
    UNSUPPORTED_OPTION = 11
    ACTIVE_AREA = 12
    RESERVED_BIT = 13
    BAD_HEADER = 14
    BAD_CRC = 15
    BAD_SCHEDULE = 16


class ApplyStatus(enum.IntEnum):
    """0x8010/0x8011:02 Status (13.2 "Status common values"); 6 is not defined."""

    OK = 0
    INVALID_STATE = 1
    INVALID_MULTIPLIER = 2
    INVALID_CHANNEL_MASK = 3
    INVALID_PROFILE = 4
    MAPPING_RELOAD_REQUIRED = 5
    ENCAPSULATION_ERROR = 7
    OVERFLOW = 8
    PENDING_APPLY = 9
    UNSUPPORTED_OPTION = 10


class TxResultCode(enum.IntEnum):
    """TX_RESULT ResultCode (chapter 10)."""

    OK = 0
    QUEUED = 1
    BUS_BUSY = 2
    INVALID_CHANNEL = 3
    TX_FIFO_FULL = 4
    BUS_OFF = 5


class HeaderFlags(enum.IntFlag):
    """header_flags bits 0-5 (chapter 6); bits 6/7 are written 0 and ignored on receipt."""

    STREAM_TRUNCATED = 0x01
    ANY_CHANNEL_ERROR = 0x02
    TX_RESULT_PRESENT = 0x04
    STATUS_CHANGED = 0x08
    SEQ_WRAP = 0x10
    OVERFLOW_SAT_VALID = 0x20


class Option(enum.IntFlag):
    """Option flags 0x8010/0x8011:07 (9.1); bits 5-7 are reserved (apply status 10)."""

    TX_RESULT_ENABLE = 0x01
    ALIGN_4_ENABLE = 0x02
    NO_CRC16_ENABLE = 0x04
    APP_BYPASS_ENABLE = 0x08
    PAYLOAD_ONLY_ENABLE = 0x10


class Feature(enum.IntFlag):
    """PDO feature flags 0xF000:16 (13.8): what the device can do at all."""

    TX_RESULT = 1 << 0
    TSF_DELTA16 = 1 << 1
    TSF_DELTA32 = 1 << 2
    TSF_FULL64 = 1 << 3
    D64 = 1 << 4
    ALIGN4 = 1 << 5
    STREAM_CRC32 = 1 << 6
    RX_TSF_SCHEDULE_TX = 1 << 8
    NO_CRC16 = 1 << 9
    APP_BYPASS = 1 << 10
    PAYLOAD_ONLY = 1 << 11
    FINE_BYPASS = 1 << 12


_NO_FLAGS = HeaderFlags(0)

#: 0xF000:16 default 0x00001F3B (13.8): no delta32, no stream CRC32.
DEFAULT_FEATURES = 0x1F3B


class Tsf(enum.IntEnum):
    """Control-word TSF: timestamp field size 0/2/4/8 bytes (8.4)."""

    NONE = 0
    DELTA16 = 1
    DELTA32 = 2
    FULL64 = 3


class PacketKind(enum.IntEnum):
    """Control-word KIND (chapter 8): only CAN_FRAME and TX_RESULT exist today; 2/3 are refused."""

    CAN_FRAME = 0
    TX_RESULT = 1
    STREAM_META = 2
    RESERVED = 3


class Direction(enum.Enum):
    """Which PDO an image is: they differ in TSF meaning (8.4) and in TX_RESULT (chapter 10)."""

    #: TxPDO / SM3 / inputs, slave to master, profile object 0x8010.
    TX = "tx"
    #: RxPDO / SM2 / outputs, master to slave, profile object 0x8011.
    RX = "rx"


class Commit(enum.Enum):
    """What a received image is relative to the last one processed (6.1, 13.8 last note)."""

    #: seq_begin == seq_end and a sequence not just processed: parse it.
    NEW = "new"
    #: The image just processed, byte for byte again: an idempotent no-op, not an error.
    SAME = "same"
    #: seq_begin != seq_end: half written, ignore this cycle.
    TORN = "torn"
    #: The sequence just processed with different contents: LastPDOError 10.
    DUPLICATE = "duplicate"


_TSF_BYTES = (0, 2, 4, 8)
_TSFS = tuple(Tsf)
_HEADER = struct.Struct("<BBHHHHHBBBB4H")
_HEADER_SEQ_END = struct.Struct("<H")
_U16 = struct.Struct("<H")
_COMMIT = struct.Struct("<HHHH")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_CTRL_STD = struct.Struct("<HH")
_CTRL_EXT = struct.Struct("<HI")
_SCHEDULE = struct.Struct("<BBHI")
_TX_RESULT = struct.Struct("<HHBB")
_LAYOUT_CRC = struct.Struct("<IHH")
#: Control-word bits a TX_RESULT leaves 0: DLC, IDE, FDF, BRS, X, TSF, D64 (chapter 10: CH + KIND).
_TX_RESULT_CTRL_ZERO = 0x9FF8
#: Zeros for a D64 window tail (< 64) plus ALIGN4 padding (< 4).
_ZERO_PAD = bytes(68)
_new_object = object.__new__


def dlc_to_len(dlc: int) -> int:
    """CAN / CAN FD DLC -> data bytes (8.2 table)."""
    return FD_DLC_TO_LEN[dlc]


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0; 5.4.4.1)."""
    return binascii.crc_hqx(data, 0xFFFF)


def profile_word(multiplier: int, channel_mask: int, profile: int, budget_policy: int, options: int) -> int:
    """The Active profile word 0x8010/0x8011:12 (13.2 bit table; the layout_word of 5.4.4.1)."""
    return (((multiplier - 1) & 0x1F) | ((channel_mask & 0xFF) << 5) | ((profile & 0x3F) << 13)
            | ((budget_policy & 0x03) << 19) | ((options & 0xFF) << 21))


def fold_layout_id(word: int) -> int:
    """layout_id = (layout_word ^ (layout_word >> 16)) & 0xFFFF (5.4.4.1 step 3)."""
    return (word ^ (word >> 16)) & 0xFFFF


def saturate_u8(n: int) -> int:
    """overflow_sat saturates at 255 (6.1) and is never negative."""
    return 0 if n < 0 else (255 if n > 255 else n)


def next_seq(seq: int) -> tuple[int, bool]:
    """The next publish sequence (16-bit wrap, 6.1) and whether it wrapped (SEQ_WRAP)."""
    nxt = (seq + 1) & 0xFFFF
    return nxt, nxt == 0


def timestamp_ticks(t: float, tsf: Tsf | int, reference: float = 0.0) -> int:
    """The TSF field for an instant ``t`` (clock seconds, e.g. the bus receive instant): delta16 /
    delta32 are the low 16 / 32 bits of ``t - reference`` in 1 us ticks (8.4: relative to the
    cycle's time base, wrapping), full64 the ticks of ``t`` itself; 0 for TSF_NONE."""
    if not tsf:
        return 0
    if tsf == Tsf.FULL64:
        return round(t / TIMESTAMP_UNIT_S) & 0xFFFFFFFFFFFFFFFF
    return round((t - reference) / TIMESTAMP_UNIT_S) & (0xFFFF if tsf == Tsf.DELTA16 else 0xFFFFFFFF)


def check_options(options: int) -> ApplyStatus:
    """Apply status for an option byte (9.1): reserved bits 5-7 (or > 8 bits) -> 10 unsupported."""
    return ApplyStatus.OK if 0 <= options <= 0xFF and not options & ~OPTION_MASK else ApplyStatus.UNSUPPORTED_OPTION


def check_layout(multiplier: int, channel_mask: int, profile: int, budget_policy: int, options: int,
                 *, max_multiplier: int = 24, channels: int = MAX_CHANNELS) -> ApplyStatus:
    """The apply status a requested profile gets on its own merits (13.2 status table, 13.8 limits).

    State (1) and mapping (5) checks need the EtherCAT state and 0x1C12/0x1C13: the device adds them.
    """
    if not 1 <= multiplier <= max_multiplier:
        return ApplyStatus.INVALID_MULTIPLIER
    if not 0 <= channel_mask <= 0xFF or channel_mask >> channels:
        return ApplyStatus.INVALID_CHANNEL_MASK
    if not 0 <= profile <= 0x3F or not (PROFILE_MASK >> profile) & 1 or budget_policy not in (0, 1, 2):
        return ApplyStatus.INVALID_PROFILE
    return check_options(options)


@dataclass(frozen=True, slots=True)
class StreamLayout:
    """One direction's active profile (0x8010 or 0x8011 after apply): what an image looks like.

    ``direction`` is not part of the profile word but decides what packets may appear (8.4,
    chapter 10): the device's RxPDO layout is ``Direction.RX``, its TxPDO layout ``Direction.TX``.
    ``features`` is 0xF000:16; tests raise it to exercise capabilities the product leaves off.
    """

    multiplier: int = 8
    channel_mask: int = 0x0F
    profile: int = 0
    budget_policy: int = BudgetPolicy.BALANCED
    options: int = 0
    direction: Direction = Direction.RX
    features: int = DEFAULT_FEATURES
    # Derived once (the hot loops read these instead of recomputing them per packet).
    _tsf_ok: int = field(init=False, repr=False, compare=False, default=0)
    _d64_ok: bool = field(init=False, repr=False, compare=False, default=False)
    _tx_result_ok: bool = field(init=False, repr=False, compare=False, default=False)
    _schedule_ok: bool = field(init=False, repr=False, compare=False, default=False)
    _rx: bool = field(init=False, repr=False, compare=False, default=True)
    _align4: bool = field(init=False, repr=False, compare=False, default=False)
    _crc: bool = field(init=False, repr=False, compare=False, default=True)

    def __post_init__(self) -> None:
        status = check_layout(self.multiplier, self.channel_mask, self.profile, int(self.budget_policy),
                              self.options)
        if status is not ApplyStatus.OK:
            raise LocalError(f"not an ECAN-Lite layout ({status.name}): {self!r}")
        object.__setattr__(self, "budget_policy", BudgetPolicy(self.budget_policy))
        feat = self.features
        tx = self.direction is Direction.TX
        stamps = self.profile in (1, 5)
        tsf_ok = 1 << Tsf.NONE
        if tx and stamps:
            for tsf, bit in ((Tsf.DELTA16, Feature.TSF_DELTA16), (Tsf.DELTA32, Feature.TSF_DELTA32),
                             (Tsf.FULL64, Feature.TSF_FULL64)):
                if feat & bit:
                    tsf_ok |= 1 << tsf
        schedule_ok = not tx and bool(feat & Feature.RX_TSF_SCHEDULE_TX)
        if schedule_ok:
            tsf_ok |= 1 << Tsf.FULL64
        object.__setattr__(self, "_tsf_ok", tsf_ok)
        object.__setattr__(self, "_schedule_ok", schedule_ok)
        object.__setattr__(self, "_rx", not tx)
        object.__setattr__(self, "_d64_ok", self.profile in (4, 5) and bool(feat & Feature.D64))
        object.__setattr__(self, "_tx_result_ok",
                           tx and bool(self.options & Option.TX_RESULT_ENABLE) and bool(feat & Feature.TX_RESULT))
        object.__setattr__(self, "_align4", bool(self.options & Option.ALIGN_4_ENABLE))
        object.__setattr__(self, "_crc", not self.options & Option.NO_CRC16_ENABLE)

    @classmethod
    def default(cls, direction: Direction = Direction.RX) -> StreamLayout:
        """The power-on requested profile (9.2): N 8, mask 0x0F, profile 0, Balanced, options 0."""
        return cls(direction=direction)

    @property
    def pdo_bytes(self) -> int:
        """ActivePDOBytes = 128 * N (5.2)."""
        return 128 * self.multiplier

    @property
    def frame_area_bytes(self) -> int:
        """ActiveFrameAreaBytes = ActivePDOBytes - 24 (5.2)."""
        return 128 * self.multiplier - HEADER_SIZE

    @property
    def profile_word(self) -> int:
        """Active profile word 0x8010/0x8011:12 (13.2)."""
        return profile_word(self.multiplier, self.channel_mask, self.profile, self.budget_policy, self.options)

    @property
    def layout_id(self) -> int:
        """The header's layout_id: the profile word folded to 16 bits (5.4.4.1)."""
        return fold_layout_id(self.profile_word)

    @property
    def layout_crc(self) -> int:
        """Active layout CRC 0x8010/0x8011:11: CRC32 (zlib) of profile word, PDO and frame-area
        bytes, little-endian (11 names it, nothing defines it; docs/decisions.md)."""
        return zlib.crc32(_LAYOUT_CRC.pack(self.profile_word, self.pdo_bytes, self.frame_area_bytes))

    @property
    def align4(self) -> bool:
        """ALIGN_4_ENABLE: packets padded to 4 bytes, padding counted in payload_len (8.3)."""
        return self._align4

    @property
    def crc_enabled(self) -> bool:
        """payload_crc16 in use (crc_alg 1) unless NO_CRC16_ENABLE (9.1)."""
        return self._crc

    @property
    def channels(self) -> tuple[int, ...]:
        """The enabled channels of this direction, ascending."""
        return tuple(ch for ch in range(MAX_CHANNELS) if self.channel_mask >> ch & 1)

    def allows_tsf(self, tsf: Tsf | int) -> bool:
        """Whether a CAN_FRAME may carry this TSF here (chapter 9 profiles, 8.4 directions)."""
        return bool(self._tsf_ok >> tsf & 1)


@dataclass(frozen=True, slots=True)
class StreamHeader:
    """The 24-byte fixed header (chapter 6), field by field."""

    header_flags: HeaderFlags = _NO_FLAGS
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
        return _HEADER.pack(self.ver_ihl, self.header_flags, self.seq_begin, self.seq_end, self.payload_len,
                            self.payload_crc16, self.layout_id, self.channel_mask, self.frame_count,
                            self.overflow_sat, self.crc_alg, *self.channel_status)

    @classmethod
    def unpack(cls, image: bytes | bytearray | memoryview) -> StreamHeader:
        """The header of an image; an image shorter than 24 bytes is StreamError ACTIVE_AREA."""
        if len(image) < HEADER_SIZE:
            raise StreamError(PdoError.ACTIVE_AREA, ParseDiag(reason=f"image of {len(image)} bytes has no header"))
        (ver_ihl, flags, seq_begin, seq_end, payload_len, crc, layout_id, mask, count, overflow, crc_alg,
         s0, s1, s2, s3) = _HEADER.unpack_from(image, 0)
        return cls(HeaderFlags(flags & 0x3F), seq_begin, seq_end, payload_len, crc, layout_id, mask, count,
                   overflow, crc_alg, (s0, s1, s2, s3), ver_ihl)


@dataclass(frozen=True, slots=True)
class CanPacket:
    """A CAN_FRAME packet (8.1): one CAN / CAN FD frame of a channel, checked once when built.

    ``timestamp`` is the raw delta16/delta32/full64 value in :data:`TIMESTAMP_UNIT_S` ticks
    (TxPDO). In the RxPDO, ``tsf=FULL64`` with ``scheduled`` is the SYNC0 reservation of 8.4/13.8:
    ``offset_ns`` after the next SYNC0, ``tag`` the master's own 16 bits. ``dlc`` is the DLC field
    (8.2): give it for classic remote frames (no data, DLC = requested length), else -1 derives it
    from ``data``. ``d64`` sends the data in a fixed 64-byte window (profiles 4/5). ``id_aux`` is
    ID_AUX (8.1). A packet no layout can carry raises :class:`StreamEncodeError` with the
    LastPDOError a receiver would report; what a particular layout allows is checked on encoding.
    """

    channel: int
    can_id: int
    extended: bool = False
    fd: bool = False
    brs: bool = False
    rtr: bool = False
    esi: bool = False
    data: bytes = b""
    tsf: Tsf = Tsf.NONE
    timestamp: int = 0
    scheduled: bool = False
    offset_ns: int = 0
    tag: int = 0
    id_aux: int = 0
    d64: bool = False
    dlc: int = -1
    # The control word (KIND 0) and the unaligned packet length, computed once (8.3).
    ctrl: int = field(init=False, repr=False, compare=False, default=0)
    raw_size: int = field(init=False, repr=False, compare=False, default=0)

    def __post_init__(self) -> None:
        data = self.data
        if type(data) is not bytes:
            if not isinstance(data, (bytes, bytearray, memoryview)):
                raise _refuse(PdoError.INVALID_DLC, f"data must be bytes, got {type(data).__name__}")
            data = bytes(data)
            object.__setattr__(self, "data", data)
        ch = self.channel
        if type(ch) is not int or not 0 <= ch <= 7:
            raise _refuse(PdoError.INVALID_CHANNEL, f"channel {ch!r} does not fit CH (0..7, chapter 8)")
        if not (isinstance(self.can_id, int) and isinstance(self.timestamp, int) and isinstance(self.offset_ns, int)
                and isinstance(self.tag, int) and isinstance(self.id_aux, int) and isinstance(self.dlc, int)):
            raise _refuse(PdoError.RESERVED_BIT, f"id, timestamp, offset_ns, tag, ID_AUX, DLC are integers: {self!r}")
        n = len(data)
        if self.fd:
            if self.rtr:
                raise _refuse(PdoError.INVALID_DLC, "CAN FD has no remote frames (8.2)")
            dlc = FD_LEN_TO_DLC.get(n, -1)
            if dlc < 0:
                raise _refuse(PdoError.INVALID_DLC, f"{n} data bytes match no CAN FD DLC (8.2)")
            x = self.esi
        else:
            if self.brs or self.esi or self.d64:
                raise _refuse(PdoError.INVALID_DLC, "BRS, ESI and D64 need CAN FD (8.2)")
            if self.rtr:
                if n:
                    raise _refuse(PdoError.INVALID_DLC, "a remote frame carries no data (8.2)")
                dlc = 0 if self.dlc == -1 else self.dlc
                if type(dlc) is not int or not 0 <= dlc <= 8:
                    raise _refuse(PdoError.INVALID_DLC, f"remote frame DLC {dlc} out of 0..8 (8.2)")
            elif n > 8:
                raise _refuse(PdoError.INVALID_DLC, f"classic CAN carries at most 8 bytes, got {n} (8.2)")
            else:
                dlc = n
            x = self.rtr
        if self.dlc not in (-1, dlc):
            raise _refuse(PdoError.INVALID_DLC, f"DLC {self.dlc} does not match {n} data bytes (8.2)")
        tsf = self.tsf
        if type(tsf) is not Tsf:
            if tsf not in (0, 1, 2, 3):
                raise _refuse(PdoError.INVALID_TSF, f"TSF {tsf!r} is not 0..3 (8.4)")
            tsf = _TSFS[tsf]
            object.__setattr__(self, "tsf", tsf)
        if self.scheduled:
            if tsf is not Tsf.FULL64:
                raise _refuse(PdoError.BAD_SCHEDULE, "scheduled transmit is TSF_FULL64 format 1 (8.4)")
            if not 0 <= self.offset_ns <= 0xFFFFFFFF or not 0 <= self.tag <= 0xFFFF or self.timestamp:
                raise _refuse(PdoError.BAD_SCHEDULE, "offset_ns is u32, tag u16, no timestamp (8.4)")
        elif self.offset_ns or self.tag:
            raise _refuse(PdoError.BAD_SCHEDULE, "offset_ns and tag belong to scheduled packets (8.4)")
        elif not 0 <= self.timestamp < 1 << (8 * _TSF_BYTES[tsf]):
            raise _refuse(PdoError.INVALID_TSF, f"timestamp {self.timestamp} does not fit TSF {tsf} (8.4)")
        if not 0 <= self.can_id <= (MAX_EXT_ID if self.extended else MAX_STD_ID) or not 0 <= self.id_aux <= 7:
            raise _refuse(PdoError.RESERVED_BIT, f"id 0x{self.can_id:X} / ID_AUX {self.id_aux} out of range (8.1)")
        object.__setattr__(self, "dlc", dlc)
        object.__setattr__(self, "ctrl", ch | dlc << 3 | bool(self.extended) << 7 | bool(self.fd) << 8
                           | bool(self.brs) << 9 | bool(x) << 10 | tsf << 11 | bool(self.d64) << 15)
        object.__setattr__(self, "raw_size", (6 if self.extended else 4) + _TSF_BYTES[tsf]
                           + (0 if self.rtr else 64 if self.d64 else n))

    @property
    def kind(self) -> PacketKind:
        """KIND 0."""
        return PacketKind.CAN_FRAME

    @property
    def frame(self) -> CanFrame:
        """The bus frame this packet describes."""
        return CanFrame(self.can_id, self.data, self.extended, self.rtr, self.fd, self.brs, self.esi,
                        self.dlc if self.rtr else -1)

    @classmethod
    def from_frame(cls, channel: int, frame: CanFrame, *, tsf: Tsf = Tsf.NONE, timestamp: int = 0,
                   id_aux: int = 0, d64: bool = False) -> CanPacket:
        """The packet carrying a bus frame received on ``channel`` (TxPDO direction)."""
        if not (frame.extended or frame.rtr or frame.fd or id_aux or d64):
            return cls.classic(channel, frame.can_id, frame.data, tsf=tsf, timestamp=timestamp)
        return cls(channel, frame.can_id, frame.extended, frame.fd, frame.brs, frame.rtr, frame.esi, frame.data,
                   tsf, timestamp, False, 0, 0, id_aux, d64, frame.dlc if frame.rtr else -1)

    @classmethod
    def classic(cls, channel: int, can_id: int, data: bytes = b"", *, tsf: Tsf = Tsf.NONE,
                timestamp: int = 0) -> CanPacket:
        """A classic 11-bit data frame, the packet of every cycle: built slot by slot after its few
        checks (a quarter of the generated ``__init__`` + ``__post_init__``, like ``CanFrame``'s own
        fast path); anything else goes the full way with the same checks and errors."""
        if (type(channel) is not int or not 0 <= channel <= 7 or type(can_id) is not int
                or not 0 <= can_id <= MAX_STD_ID or type(data) is not bytes or len(data) > 8
                or type(tsf) is not Tsf or tsf is Tsf.FULL64 or type(timestamp) is not int
                or not 0 <= timestamp < 1 << 8 * _TSF_BYTES[tsf]):
            return cls(channel, can_id, data=data, tsf=tsf, timestamp=timestamp)
        n = len(data)
        p: CanPacket = _new_object(cls)
        (s_ch, s_id, s_ext, s_fd, s_brs, s_rtr, s_esi, s_data, s_tsf, s_ts, s_sched, s_off, s_tag, s_aux, s_d64,
         s_dlc, s_ctrl, s_raw) = _CAN_PACKET_SETTERS
        s_ch(p, channel)
        s_id(p, can_id)
        s_ext(p, False)
        s_fd(p, False)
        s_brs(p, False)
        s_rtr(p, False)
        s_esi(p, False)
        s_data(p, data)
        s_tsf(p, tsf)
        s_ts(p, timestamp)
        s_sched(p, False)
        s_off(p, 0)
        s_tag(p, 0)
        s_aux(p, 0)
        s_d64(p, False)
        s_dlc(p, n)
        s_ctrl(p, channel | n << 3 | tsf << 11)
        s_raw(p, 4 + _TSF_BYTES[tsf] + n)
        return p


#: The slot setters of CanPacket in field order: the decoder builds packets it has already checked
#: without the generated __init__ (half the cost per packet; the same trick as CanFrame).
_CAN_PACKET_SETTERS: tuple[Callable[[CanPacket, Any], None], ...] = tuple(
    vars(CanPacket)[f.name].__set__ for f in fields(CanPacket))


@dataclass(frozen=True, slots=True)
class TxResultPacket:
    """A TX_RESULT packet (chapter 10): the outcome of frame ``ref_frame_index`` (counting KIND 0
    packets from 0) of the RxPDO image committed with sequence ``ref_packet_seq``."""

    channel: int
    ref_packet_seq: int
    ref_frame_index: int
    result: TxResultCode

    def __post_init__(self) -> None:
        ch = self.channel
        if type(ch) is not int or not 0 <= ch <= 7:
            raise _refuse(PdoError.INVALID_CHANNEL, f"channel {ch!r} does not fit CH (0..7, chapter 8)")
        seq, index = self.ref_packet_seq, self.ref_frame_index
        if not isinstance(seq, int) or not isinstance(index, int) or not 0 <= seq <= 0xFFFF or not 0 <= index <= 0xFF:
            raise _refuse(PdoError.UNKNOWN_KIND, "RefPacketSeq is u16, RefFrameIndex u8 (10)")
        if type(self.result) is not TxResultCode:
            if self.result not in _RESULT_VALUES:
                raise _refuse(PdoError.UNKNOWN_KIND, f"ResultCode {self.result!r} is not 0..5 (10)")
            object.__setattr__(self, "result", TxResultCode(self.result))

    @property
    def kind(self) -> PacketKind:
        """KIND 1."""
        return PacketKind.TX_RESULT

    @property
    def ctrl(self) -> int:
        """The control word: CH and KIND 1 (chapter 10)."""
        return self.channel | 1 << 13


Packet = CanPacket | TxResultPacket
_RESULT_CODES = tuple(TxResultCode)
_RESULT_VALUES = frozenset(range(6))


@dataclass(frozen=True, slots=True)
class ParseDiag:
    """Where a parse failed: the IgH package's parse_diag fields (16.2); -1 = not reached."""

    offset: int = -1
    packet_end: int = -1
    ctrl: int = -1
    seq: int = -1
    payload_len: int = -1
    crc: int = -1
    layout_id: int = -1
    ch: int = -1
    dlc: int = -1
    tsf: int = -1
    kind: int = -1
    reason: str = ""


class StreamError(ProtocolError):
    """An image the receiver rejects: ``code`` is its LastPDOError (13.2), ``diag`` says where."""

    def __init__(self, code: PdoError, diag: ParseDiag | None = None) -> None:
        diag = diag if diag is not None else ParseDiag()
        super().__init__(f"{code.name} ({int(code)}): {diag.reason}" if diag.reason else code.name, int(code))
        self.pdo_error = code
        self.diag = diag

    def __reduce__(self) -> tuple[type[StreamError], tuple[PdoError, ParseDiag]]:
        return (StreamError, (self.pdo_error, self.diag))


class StreamEncodeError(LocalError, ValueError):
    """A packet this layout cannot carry, refused before anything is written; ``pdo_error`` is the
    LastPDOError the receiver would report for it."""

    def __init__(self, code: PdoError, message: str) -> None:
        super().__init__(f"{code.name} ({int(code)}): {message}", int(code))
        self.pdo_error = code


@dataclass(frozen=True, slots=True)
class DecodedStream:
    """A parsed image: its header and packets in stream order."""

    header: StreamHeader
    packets: tuple[Packet, ...]

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


# --------------------------------------------------------------------------------------------- encode

def _refuse(code: PdoError, message: str) -> StreamEncodeError:
    return StreamEncodeError(code, message)


def _layout_refusal(p: Packet, layout: StreamLayout) -> StreamEncodeError | None:
    """Why ``layout`` cannot carry ``p``, by the receiver's own rules (:func:`_ctrl_error`)."""
    code, why = _ctrl_error(p.ctrl, layout)
    if code:
        return _refuse(code, why)
    if type(p) is CanPacket and p.tsf is Tsf.FULL64 and p.scheduled != layout._schedule_ok:
        return _refuse(PdoError.BAD_SCHEDULE, "TSF_FULL64 is the reservation format in the RxPDO and a timestamp "
                                              "in the TxPDO (8.4)")
    return None


def packet_size(packet: Packet, layout: StreamLayout) -> int:
    """Bytes ``packet`` occupies in ``layout``'s frame area, ALIGN4 padding included (8.3).

    Raises :class:`StreamEncodeError` for a packet this layout cannot carry.
    """
    if type(packet) is not CanPacket and type(packet) is not TxResultPacket:
        raise LocalError(f"not a packet: {packet!r}")
    refusal = _layout_refusal(packet, layout)
    if refusal is not None:
        raise refusal
    raw = packet.raw_size if type(packet) is CanPacket else 6
    return (raw + 3) & ~3 if layout._align4 else raw


def encode_into(buf: bytearray | memoryview, layout: StreamLayout, seq: int, packets: Sequence[Packet], *,
                status_words: Sequence[int] = (0, 0, 0, 0), flags: HeaderFlags | int = 0,
                overflow_sat: int = 0) -> int:
    """Write one committed image into ``buf`` (``layout.pdo_bytes`` long); returns payload_len.

    Order of 5.4.4.1 step 4: packets from offset 24, the rest of the frame area zeroed (left as it
    is with PAYLOAD_ONLY_ENABLE, whose receivers ignore it, 9.1), header, seq_end last.
    TX_RESULT_PRESENT is set when a TX_RESULT is among ``packets``; ``overflow_sat`` saturates.
    Nothing is written when a packet is refused (:class:`StreamEncodeError`).
    """
    if len(buf) != layout.pdo_bytes:
        raise LocalError(f"image buffer is {len(buf)} bytes, the layout needs {layout.pdo_bytes}")
    if len(packets) > MAX_FRAME_COUNT:
        raise _refuse(PdoError.PACKET_OVERRUN, f"{len(packets)} packets; frame_count holds at most 255")
    if len(status_words) != 4:
        raise LocalError("four channel status words (chapter 7)")
    end = layout.pdo_bytes
    align4 = layout._align4
    # Check every packet before writing one (a refused image leaves the buffer as it was); each
    # distinct control word is judged once.
    accepted: set[int] = set()
    off = HEADER_SIZE
    for p in packets:
        if type(p) is CanPacket:
            raw = p.raw_size
            if p.ctrl not in accepted or p.tsf is Tsf.FULL64:
                refusal = _layout_refusal(p, layout)
                if refusal is not None:
                    raise refusal
                accepted.add(p.ctrl)
        elif type(p) is TxResultPacket:
            raw = 6
            refusal = _layout_refusal(p, layout)
            if refusal is not None:
                raise refusal
        else:
            raise LocalError(f"not a packet: {p!r}")
        off += (raw + 3) & ~3 if align4 else raw
    if off > end:
        raise _refuse(PdoError.PACKET_OVERRUN, f"packets need {off - HEADER_SIZE} bytes, the frame area has "
                                               f"{end - HEADER_SIZE} (chapter 12)")
    flags = int(flags) & 0x3F
    off = HEADER_SIZE
    pack_std = _CTRL_STD.pack_into
    pack_ext = _CTRL_EXT.pack_into
    for p in packets:
        if type(p) is CanPacket:
            raw = p.raw_size
            if p.extended:
                pack_ext(buf, off, p.ctrl, p.can_id | p.id_aux << 29)
                o = off + 6
            else:
                pack_std(buf, off, p.ctrl, p.can_id | p.id_aux << 11)
                o = off + 4
            tsf = p.tsf
            if tsf:
                if p.scheduled:
                    _SCHEDULE.pack_into(buf, o, 1, 0, p.tag, p.offset_ns)
                    o += 8
                elif tsf == 1:
                    _U16.pack_into(buf, o, p.timestamp)
                    o += 2
                elif tsf == 2:
                    _U32.pack_into(buf, o, p.timestamp)
                    o += 4
                else:
                    _U64.pack_into(buf, o, p.timestamp)
                    o += 8
            data = p.data
            n = len(data)
            buf[o:o + n] = data
            nxt = off + raw
            if align4 and raw & 3:
                nxt = off + (raw + 3 & ~3)
            if o + n != nxt:      # D64 window tail and ALIGN4 padding: zeros (8.1, 8.3)
                buf[o + n:nxt] = _ZERO_PAD[:nxt - o - n]
            off = nxt
        else:
            assert type(p) is TxResultPacket
            _TX_RESULT.pack_into(buf, off, p.ctrl, p.ref_packet_seq, p.ref_frame_index, p.result)
            if align4:
                buf[off + 6:off + 8] = b"\0\0"
                off += 8
            else:
                off += 6
            flags |= 0x04  # HeaderFlags.TX_RESULT_PRESENT
    if not layout.options & Option.PAYLOAD_ONLY_ENABLE:
        buf[off:end] = bytes(end - off)
    payload_len = off - HEADER_SIZE
    if layout._crc:
        crc = binascii.crc_hqx(memoryview(buf)[HEADER_SIZE:off], 0xFFFF)
        alg = CRC_ALG_CCITT_FALSE
    else:
        crc = alg = 0
    seq &= 0xFFFF
    s0, s1, s2, s3 = status_words
    # seq_end (offset 4) is packed too but written again last, the commit of 5.4.4.1 step 4.
    _HEADER.pack_into(buf, 0, VER_IHL, flags, seq, (seq - 1) & 0xFFFF, payload_len, crc, layout.layout_id,
                      layout.channel_mask, len(packets), saturate_u8(overflow_sat), alg,
                      s0 & 0xFFFF, s1 & 0xFFFF, s2 & 0xFFFF, s3 & 0xFFFF)
    _HEADER_SEQ_END.pack_into(buf, 4, seq)
    return payload_len


def encode_stream(layout: StreamLayout, seq: int, packets: Sequence[Packet], *,
                  status_words: Sequence[int] = (0, 0, 0, 0), flags: HeaderFlags | int = 0,
                  overflow_sat: int = 0) -> bytes:
    """One committed image of exactly ``layout.pdo_bytes`` bytes, unused area zeroed (5.4.4.1)."""
    buf = bytearray(layout.pdo_bytes)
    encode_into(buf, layout, seq, packets, status_words=status_words, flags=flags, overflow_sat=overflow_sat)
    return bytes(buf)


# --------------------------------------------------------------------------------------------- decode

def commit_state(image: bytes | bytearray | memoryview, previous: bytes | bytearray | memoryview | None) -> Commit:
    """Whether to parse ``image`` given the last image processed (``None`` after a session reset).

    TORN when seq_begin != seq_end (6.1 step 2); SAME when ``previous`` has the same sequence and
    the same header and payload bytes (13.8: a stopped master leaves the last image, an idempotent
    no-op); with the same sequence but other contents, TORN while payload_crc16 does not match
    (5.4.4.1 writes the frame area before the new seq_begin: a write in progress) and DUPLICATE
    (LastPDOError 10) once it does; else NEW. Bytes beyond payload_len do not count (PAYLOAD_ONLY,
    9.1). Pass the last committed image whether it was accepted or rejected, so a repeated bad
    image is not counted twice.
    """
    if len(image) < HEADER_SIZE:
        raise StreamError(PdoError.ACTIVE_AREA, ParseDiag(reason=f"image of {len(image)} bytes has no header"))
    seq_begin, seq_end, payload_len, crc = _COMMIT.unpack_from(image, 2)
    if seq_begin != seq_end:
        return Commit.TORN
    if previous is None or len(previous) < HEADER_SIZE or _U16.unpack_from(previous, 2)[0] != seq_begin:
        return Commit.NEW
    n = HEADER_SIZE + payload_len
    if bytes(image[:n]) == bytes(previous[:n]):
        return Commit.SAME
    if image[15] == CRC_ALG_CCITT_FALSE and n <= len(image) and binascii.crc_hqx(image[HEADER_SIZE:n], 0xFFFF) != crc:
        return Commit.TORN
    return Commit.DUPLICATE


def decode_stream(image: bytes | bytearray | memoryview, layout: StreamLayout) -> DecodedStream:
    """Parse one image of ``layout`` (6.1 order), raising :class:`StreamError` at the first error.

    Header: length = ActivePDOBytes (else 12), ver_ihl 0x16 (14), seq_begin == seq_end (14, use
    :func:`commit_state` first to skip torn images quietly), crc_alg 1, or 0 with a zero CRC under
    NO_CRC16 (14), payload_len <= ActiveFrameAreaBytes (3), CRC over [24, 24+payload_len) (15),
    layout_id and channel_mask = the active profile's (12). Packets: each as chapter 8, ending
    within payload_len (8); then frame_count = the packets found (14). Bytes after payload_len
    are ignored (PAYLOAD_ONLY, 9.1).
    """
    size = len(image)
    if size != layout.pdo_bytes:
        raise StreamError(PdoError.ACTIVE_AREA, ParseDiag(
            reason=f"image of {size} bytes, the active layout has {layout.pdo_bytes} (5.2)"))
    (ver_ihl, flags, seq, seq_end, payload_len, crc, layout_id, mask, count, overflow, crc_alg,
     s0, s1, s2, s3) = _HEADER.unpack_from(image, 0)

    def fail(code: PdoError, reason: str, offset: int = -1, packet_end: int = -1, ctrl: int = -1) -> StreamError:
        if ctrl < 0:
            return StreamError(code, ParseDiag(offset, packet_end, -1, seq, payload_len, crc, layout_id,
                                               reason=reason))
        return StreamError(code, ParseDiag(offset, packet_end, ctrl, seq, payload_len, crc, layout_id,
                                           ctrl & 7, ctrl >> 3 & 15, ctrl >> 11 & 3, ctrl >> 13 & 3, reason))

    if ver_ihl != VER_IHL:
        raise fail(PdoError.BAD_HEADER, f"ver_ihl 0x{ver_ihl:02X}, expected 0x16 (chapter 6)")
    if seq != seq_end:
        raise fail(PdoError.BAD_HEADER, f"torn image: seq_begin {seq} != seq_end {seq_end} (6.1)")
    if layout._crc:
        if crc_alg != CRC_ALG_CCITT_FALSE:
            raise fail(PdoError.BAD_HEADER, f"crc_alg {crc_alg}, expected 1 (6.1)")
    elif crc_alg != 0 or crc != 0:
        raise fail(PdoError.BAD_HEADER, f"crc_alg {crc_alg} / crc 0x{crc:04X}, NO_CRC16 expects 0 / 0 (9.1)")
    end = HEADER_SIZE + payload_len
    if end > size:
        raise fail(PdoError.PACKET_OVERRUN, f"payload_len {payload_len} > frame area {size - HEADER_SIZE} (6.1)")
    if layout._crc:
        # (a copy, not a memoryview: a view kept alive by a traceback would pin the caller's bytearray)
        calc = binascii.crc_hqx(image[HEADER_SIZE:end], 0xFFFF)
        if calc != crc:
            raise fail(PdoError.BAD_CRC, f"payload_crc16 0x{crc:04X} != 0x{calc:04X} (6.1)")
    if layout_id != layout.layout_id or mask != layout.channel_mask:
        raise fail(PdoError.ACTIVE_AREA, f"layout_id 0x{layout_id:04X} / channel_mask 0x{mask:02X}, active "
                                         f"0x{layout.layout_id:04X} / 0x{layout.channel_mask:02X} (5.4.4.1)")
    data = image if type(image) is bytes else bytes(image)
    packets: list[Packet] = []
    append = packets.append
    # Control word -> its checked geometry, filled on first sight: an image repeats few distinct
    # control words, so each is validated once per image instead of once per packet.
    geo: dict[int, tuple[int, int, int, int, Tsf, bool, bool, bool, bool, bool, int]] = {}
    geometry = _ctrl_geometry
    new = _new_object
    (s_ch, s_id, s_ext, s_fd, s_brs, s_rtr, s_esi, s_data, s_tsf, s_ts, s_sched, s_off, s_tag, s_aux, s_d64,
     s_dlc, s_ctrl, s_raw) = _CAN_PACKET_SETTERS
    schedule_ok = layout._schedule_ok
    scheduled = schedule_ok     # in an RxPDO every packet with a TSF is a TSF_FULL64 reservation
    align4 = layout._align4
    u16 = _U16.unpack_from
    u32 = _U32.unpack_from
    off = HEADER_SIZE
    while off < end:
        if off + 2 > end:
            raise fail(PdoError.TRUNCATED, "control word cut by payload_len (8)", off, off + 2)
        ctrl = u16(data, off)[0]
        g = geo.get(ctrl)
        if g is None:
            code, why = _ctrl_error(ctrl, layout)
            if code:
                raise fail(code, why, off, -1, ctrl)
            g = geo[ctrl] = geometry(ctrl)
        id_bytes, ts_bytes, data_bytes, n, tsf, ide, fdf, brs, rtr, esi, dlc = g
        if id_bytes == 0:   # TX_RESULT (checked by _ctrl_error: KIND 1 allowed here)
            pend = off + 6
            nxt = off + 8 if align4 else pend
            if nxt > end:
                raise fail(PdoError.TRUNCATED, "TX_RESULT cut by payload_len (10)", off, nxt, ctrl)
            _c, ref_seq, ref_index, result = _TX_RESULT.unpack_from(data, off)
            if result > 5:
                raise fail(PdoError.UNKNOWN_KIND, f"ResultCode {result} undefined (10)", off, nxt, ctrl)
            if nxt != pend and data[pend] | data[pend + 1]:
                raise fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", off, nxt, ctrl)
            append(TxResultPacket(ctrl & 7, ref_seq, ref_index, _RESULT_CODES[result]))
            off = nxt
            continue
        o = off + 2 + id_bytes
        data_at = o + ts_bytes
        pend = data_at + data_bytes
        nxt = off + (pend - off + 3 & ~3) if align4 else pend
        if nxt > end:
            raise fail(PdoError.TRUNCATED, f"packet ends at {nxt} beyond payload end {end} (8.3)", off, nxt, ctrl)
        if ide:
            word = u32(data, off + 2)[0]
            can_id = word & 0x1FFFFFFF
            id_aux = word >> 29
        else:
            word = u16(data, off + 2)[0]
            if word & 0xC000:
                raise fail(PdoError.RESERVED_BIT, "StdIdField bits 14/15 must be 0 (8.1)", off, nxt, ctrl)
            can_id = word & 0x7FF
            id_aux = word >> 11
        stamp = offset_ns = tag = 0
        if ts_bytes:
            if schedule_ok:     # RxPDO: TSF_FULL64 is only the reservation format (8.4)
                fmt, sflags, tag, offset_ns = _SCHEDULE.unpack_from(data, o)
                if fmt != 1 or sflags:
                    raise fail(PdoError.BAD_SCHEDULE, f"reservation format {fmt} flags {sflags}, expected 1 / 0 "
                                                      "(8.4)", off, nxt, ctrl)
            else:
                stamp = (u16 if ts_bytes == 2 else u32 if ts_bytes == 4 else _U64.unpack_from)(data, o)[0]
        # The packet, slot by slot (checked above; no __init__ / __post_init__ round).
        pkt = new(CanPacket)
        s_ch(pkt, ctrl & 7)
        s_id(pkt, can_id)
        s_ext(pkt, ide)
        s_fd(pkt, fdf)
        s_brs(pkt, brs)
        s_rtr(pkt, rtr)
        s_esi(pkt, esi)
        s_data(pkt, data[data_at:data_at + n])
        s_tsf(pkt, tsf)
        s_ts(pkt, stamp)
        s_sched(pkt, scheduled and ts_bytes != 0)
        s_off(pkt, offset_ns)
        s_tag(pkt, tag)
        s_aux(pkt, id_aux)
        s_d64(pkt, ctrl >= 0x8000)
        s_dlc(pkt, dlc)
        s_ctrl(pkt, ctrl)
        s_raw(pkt, pend - off)
        if nxt != pend and data[pend:nxt].count(0) != nxt - pend:
            raise fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", off, nxt, ctrl)
        append(pkt)
        off = nxt
    if len(packets) != count:
        raise fail(PdoError.BAD_HEADER, f"frame_count {count} but {len(packets)} packets in payload_len (6)", off)
    header = StreamHeader(HeaderFlags(flags & 0x3F), seq, seq_end, payload_len, crc, layout_id, mask, count,
                          overflow, crc_alg, (s0, s1, s2, s3), ver_ihl)
    return DecodedStream(header, tuple(packets))


def _ctrl_error(ctrl: int, layout: StreamLayout) -> tuple[PdoError, str]:
    """The LastPDOError a control word alone earns in ``layout`` (chapter 8, 8.2, 8.4, 9, 10)."""
    kind = ctrl >> 13 & 3
    ch = ctrl & 7
    if kind and (kind != PacketKind.TX_RESULT or not layout._tx_result_ok):
        return PdoError.UNKNOWN_KIND, f"KIND {kind} not supported here (chapter 8, 9.1)"
    mask = layout.channel_mask & ((1 << MAX_CHANNELS) - 1)
    if not mask >> ch & 1:
        return PdoError.INVALID_CHANNEL, f"channel {ch} not in mask 0x{mask:02X} (8, 13.2)"
    if kind:
        if ctrl & _TX_RESULT_CTRL_ZERO:
            return PdoError.RESERVED_BIT, "TX_RESULT control word carries only CH and KIND (10)"
        return PdoError.OK, ""
    fdf = ctrl & 0x100
    d64 = ctrl & 0x8000
    if not fdf and (ctrl >> 3 & 15 > 8 or ctrl & 0x200 or d64):
        return PdoError.INVALID_DLC, "classic CAN: DLC <= 8, BRS = 0, D64 = 0 (8.2)"
    if d64 and not layout._d64_ok:
        return PdoError.FRAME_OVERRUN, f"D64 window not allowed in profile {layout.profile} (9)"
    tsf = ctrl >> 11 & 3
    if not layout._tsf_ok >> tsf & 1:
        if layout._rx and tsf == Tsf.FULL64:
            return PdoError.BAD_SCHEDULE, "scheduled transmit (RX_TSF_SCHEDULE_TX) not supported (8.4)"
        return PdoError.INVALID_TSF, f"TSF {tsf} not allowed in this profile/direction (8.4, 9)"
    return PdoError.OK, ""


def _ctrl_geometry(ctrl: int) -> tuple[int, int, int, int, Tsf, bool, bool, bool, bool, bool, int]:
    """(id bytes (0 = TX_RESULT), timestamp bytes, data bytes on the wire, data bytes of the frame,
    TSF, IDE, FDF, BRS, RTR, ESI, DLC) of a control word that passed
    :func:`_ctrl_error` (8.3)."""
    if ctrl >> 13 & 3:
        return 0, 0, 0, 0, Tsf.NONE, False, False, False, False, False, -1
    dlc = ctrl >> 3 & 15
    fdf = ctrl & 0x100 != 0
    x = ctrl & 0x400 != 0
    rtr = x and not fdf
    tsf = _TSFS[ctrl >> 11 & 3]
    n = 0 if rtr else FD_DLC_TO_LEN[dlc]
    wire = 64 if ctrl & 0x8000 else n
    return (4 if ctrl & 0x80 else 2, _TSF_BYTES[tsf], wire, n, tsf, ctrl & 0x80 != 0, fdf, ctrl & 0x200 != 0, rtr,
            x and fdf, dlc)
