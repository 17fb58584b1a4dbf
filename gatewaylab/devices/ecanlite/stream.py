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
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from gatewaylab.bus.frame import FD_DLC_TO_LEN, FD_LEN_TO_DLC, MAX_EXT_ID, MAX_STD_ID, CanFrame
from gatewaylab.common.errors import LocalError, ProtocolError
from gatewaylab.devices.ecanlite.budget import BudgetPolicy

__all__ = [
    "CRC_ALG_CCITT_FALSE",
    "DEFAULT_FEATURES",
    "HEADER_SIZE",
    "MAX_CHANNELS",
    "MAX_FRAME_COUNT",
    "OPTION_MASK",
    "PROFILE_MASK",
    "TIMESTAMP_UNIT_S",
    "VER_IHL",
    "CanPacket",
    "Commit",
    "DecodedStream",
    "Direction",
    "Feature",
    "HeaderFlags",
    "Option",
    "Packet",
    "PacketKind",
    "ParseDiag",
    "PdoError",
    "ProfileStatus",
    "StreamEncodeError",
    "StreamError",
    "StreamHeader",
    "StreamLayout",
    "Tsf",
    "TxResultCode",
    "TxResultPacket",
    "check_layout",
    "check_options",
    "commit_state",
    "crc16",
    "decode_stream",
    "dlc_to_len",
    "encode_into",
    "encode_stream",
    "fold_layout_id",
    "next_seq",
    "packet_size",
    "profile_word",
    "saturate_u8",
    "timestamp_ticks",
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


class ProfileStatus(enum.IntEnum):
    """0x8010/0x8011:02 Status of a profile apply (13.2 "Status common values"); 6 is not defined.
    Not the MCAN channel's 0x800x:02 'Apply status' (13.4): that is ``mcan.ApplyStatus``."""

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
_TX_RESULT = struct.Struct("<HHBB")
#: A CAN_FRAME's control word, id field and timestamp field in one format (8.1, 8.4), by
#: [IDE][shape]: shape 0 no timestamp, 1 delta16, 2 delta32, 3 full64, 4 the RxPDO reservation
#: (format u8, flags u8, tag u16, offset_ns u32). The packet packs its head with these, the
#: decoder unpacks a head with one call.
_PACKET_HEADS = tuple(tuple(struct.Struct("<H" + id_fmt + ts_fmt) for ts_fmt in ("", "H", "I", "Q", "BBHI"))
                      for id_fmt in ("H", "I"))
_LAYOUT_CRC = struct.Struct("<IHH")
#: Control-word bits a TX_RESULT leaves 0: DLC, IDE, FDF, BRS, X, TSF, D64 (chapter 10: CH + KIND).
_TX_RESULT_CTRL_ZERO = 0x9FF8
#: Control-word TSF bits 11-12 both set: TSF_FULL64 (a TX_RESULT leaves them 0).
_TSF_FULL64 = 0x1800
#: TSF bits and KIND bits: a control word with none of them needs no per-packet check on encoding.
_TSF_FULL64_OR_KIND = 0x7800
#: Zeros for a D64 window tail (< 64) plus ALIGN4 padding (< 4).
_ZERO_PAD = bytes(68)
_new_object = object.__new__
#: ``__class__`` of a frozen packet is set through object's own __setattr__ (CanPacket.__init__).
_set_class = object.__setattr__
#: Appended to the decoder's copy of an image, so a packet head can be unpacked before the check
#: that it ends inside payload_len (a full64 head is 2 + 4 + 8 bytes).
_DECODE_TAIL = bytes(16)
#: What the decoder needs of a control word that passed :func:`_ctrl_error` (:func:`_ctrl_geometry`).
_Geometry = tuple[Any, ...]


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


def check_options(options: int) -> ProfileStatus:
    """Apply status for an option byte (9.1): reserved bits 5-7 (or > 8 bits) -> 10 unsupported."""
    return ProfileStatus.OK if 0 <= options <= 0xFF and not options & ~OPTION_MASK else ProfileStatus.UNSUPPORTED_OPTION


def check_layout(multiplier: int, channel_mask: int, profile: int, budget_policy: int, options: int,
                 *, max_multiplier: int = 24, channels: int = MAX_CHANNELS) -> ProfileStatus:
    """The apply status a requested profile gets on its own merits (13.2 status table, 13.8 limits).

    State (1) and mapping (5) checks need the EtherCAT state and 0x1C12/0x1C13: the device adds them.
    """
    if not 1 <= multiplier <= max_multiplier:
        return ProfileStatus.INVALID_MULTIPLIER
    if not 0 <= channel_mask <= 0xFF or channel_mask >> channels:
        return ProfileStatus.INVALID_CHANNEL_MASK
    if not 0 <= profile <= 0x3F or not (PROFILE_MASK >> profile) & 1 or budget_policy not in (0, 1, 2):
        return ProfileStatus.INVALID_PROFILE
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
    # Control word -> its checked geometry (:func:`_ctrl_geometry`), filled on first sight: a
    # stream repeats few distinct control words, so each is judged once per layout, not per packet.
    _geo: dict[int, _Geometry] = field(init=False, repr=False, compare=False, default_factory=dict)
    # The accepted control words of CAN_FRAMEs without TSF_FULL64: an encoder whose control words
    # are all here needs no further check (FULL64 depends on the packet, TX_RESULT sets a flag).
    _plain: set[int] = field(init=False, repr=False, compare=False, default_factory=set)

    def __post_init__(self) -> None:
        status = check_layout(self.multiplier, self.channel_mask, self.profile, int(self.budget_policy),
                              self.options)
        if status is not ProfileStatus.OK:
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

    def __reduce__(self) -> tuple[type[StreamLayout], tuple[Any, ...]]:
        # Pickled / copied by its profile fields: the caches are rebuilt, never carried along.
        return (StreamLayout, (self.multiplier, self.channel_mask, self.profile, self.budget_policy, self.options,
                               self.direction, self.features))

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
    # The packet's bytes on the wire (8.1, 8.3 without ALIGN4 padding): encoding joins them.
    _wire: bytes = field(init=False, repr=False, compare=False, default=b"")

    def __init__(self, channel: int, can_id: int, extended: bool = False, fd: bool = False, brs: bool = False,
                 rtr: bool = False, esi: bool = False, data: bytes = b"", tsf: Tsf = Tsf.NONE, timestamp: int = 0,
                 scheduled: bool = False, offset_ns: int = 0, tag: int = 0, id_aux: int = 0, d64: bool = False,
                 dlc: int = -1) -> None:
        # Written out (dataclass keeps an explicit __init__; the fields above stay the record):
        # checked from the arguments, then every slot stored once, ~1.5 us instead of the ~4 us
        # of the generated __init__ + __post_init__ (docs/decisions.md, issue 10 speed).
        if type(data) is not bytes:
            if not isinstance(data, (bytes, bytearray, memoryview)):
                raise _refuse(PdoError.INVALID_DLC, f"data must be bytes, got {type(data).__name__}")
            data = bytes(data)
        if type(channel) is not int or not 0 <= channel <= 7:
            raise _refuse(PdoError.INVALID_CHANNEL, f"channel {channel!r} does not fit CH (0..7, chapter 8)")
        if not (isinstance(can_id, int) and isinstance(timestamp, int) and isinstance(offset_ns, int)
                and isinstance(tag, int) and isinstance(id_aux, int) and isinstance(dlc, int)):
            raise _refuse(PdoError.RESERVED_BIT, "id, timestamp, offset_ns, tag, ID_AUX, DLC are integers: "
                                                 f"{(can_id, timestamp, offset_ns, tag, id_aux, dlc)!r}")
        n = len(data)
        if fd:
            if rtr:
                raise _refuse(PdoError.INVALID_DLC, "CAN FD has no remote frames (8.2)")
            code = FD_LEN_TO_DLC.get(n, -1)
            if code < 0:
                raise _refuse(PdoError.INVALID_DLC, f"{n} data bytes match no CAN FD DLC (8.2)")
            x = esi
        else:
            if brs or esi or d64:
                raise _refuse(PdoError.INVALID_DLC, "BRS, ESI and D64 need CAN FD (8.2)")
            if rtr:
                if n:
                    raise _refuse(PdoError.INVALID_DLC, "a remote frame carries no data (8.2)")
                code = 0 if dlc == -1 else dlc
                if not 0 <= code <= 8:
                    raise _refuse(PdoError.INVALID_DLC, f"remote frame DLC {code} out of 0..8 (8.2)")
            elif n > 8:
                raise _refuse(PdoError.INVALID_DLC, f"classic CAN carries at most 8 bytes, got {n} (8.2)")
            else:
                code = n
            x = rtr
        if dlc != -1 and dlc != code:
            raise _refuse(PdoError.INVALID_DLC, f"DLC {dlc} does not match {n} data bytes (8.2)")
        if type(tsf) is not Tsf:
            if tsf not in (0, 1, 2, 3):
                raise _refuse(PdoError.INVALID_TSF, f"TSF {tsf!r} is not 0..3 (8.4)")
            tsf = _TSFS[tsf]
        if scheduled:
            if tsf is not Tsf.FULL64:
                raise _refuse(PdoError.BAD_SCHEDULE, "scheduled transmit is TSF_FULL64 format 1 (8.4)")
            if not 0 <= offset_ns <= 0xFFFFFFFF or not 0 <= tag <= 0xFFFF or timestamp:
                raise _refuse(PdoError.BAD_SCHEDULE, "offset_ns is u32, tag u16, no timestamp (8.4)")
        elif offset_ns or tag:
            raise _refuse(PdoError.BAD_SCHEDULE, "offset_ns and tag belong to scheduled packets (8.4)")
        elif not 0 <= timestamp < 1 << (8 * _TSF_BYTES[tsf]):
            raise _refuse(PdoError.INVALID_TSF, f"timestamp {timestamp} does not fit TSF {tsf} (8.4)")
        if not 0 <= can_id <= (MAX_EXT_ID if extended else MAX_STD_ID) or not 0 <= id_aux <= 7:
            raise _refuse(PdoError.RESERVED_BIT, f"id 0x{can_id:X} / ID_AUX {id_aux} out of range (8.1)")
        ide = 1 if extended else 0
        ctrl = channel | code << 3 | ide << 7 | bool(fd) << 8 | bool(brs) << 9 | bool(x) << 10 | tsf << 11 \
            | bool(d64) << 15
        ident = can_id | id_aux << (29 if ide else 11)
        if scheduled:
            wire = _PACKET_HEADS[ide][4].pack(ctrl, ident, 1, 0, tag, offset_ns)
        elif tsf:
            wire = _PACKET_HEADS[ide][tsf].pack(ctrl, ident, timestamp)
        else:
            wire = _PACKET_HEADS[ide][0].pack(ctrl, ident)
        wire += data + _ZERO_PAD[:64 - n] if d64 else data
        # Stored as the decoder does: as a _CanPacketDraft (same slots, plain stores), then frozen.
        me: Any = self
        _set_class(me, "__class__", _CanPacketDraft)
        me.channel = channel
        me.can_id = can_id
        me.extended = extended
        me.fd = fd
        me.brs = brs
        me.rtr = rtr
        me.esi = esi
        me.data = data
        me.tsf = tsf
        me.timestamp = timestamp
        me.scheduled = scheduled
        me.offset_ns = offset_ns
        me.tag = tag
        me.id_aux = id_aux
        me.d64 = d64
        me.dlc = code
        me.ctrl = ctrl
        me.raw_size = len(wire)
        me._wire = wire
        me.__class__ = CanPacket

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
        return cls(channel, frame.can_id, frame.extended, frame.fd, frame.brs, frame.rtr, frame.esi, frame.data,
                   tsf, timestamp, False, 0, 0, id_aux, d64, frame.dlc if frame.rtr else -1)

    @classmethod
    def classic(cls, channel: int, can_id: int, data: bytes = b"", *, tsf: Tsf = Tsf.NONE,
                timestamp: int = 0) -> CanPacket:
        """A classic 11-bit data frame, the packet of almost every cycle (the MCAN Port's
        ``send_can``): the constructor with the other fields at their defaults."""
        return cls(channel, can_id, data=data, tsf=tsf, timestamp=timestamp)


class _CanPacketDraft:
    """A CanPacket under construction: the same slots without the frozen ``__setattr__``.

    The decoder (and :meth:`CanPacket.__init__`, after its checks) fills one slot by slot with
    plain attribute stores, then turns it into the frozen :class:`CanPacket` it is by assigning
    ``__class__`` (the layouts are identical; CPython allows the swap for equal slot layouts).
    Storing 19 slots costs ~0.3 us this way, ~0.9 us through slot-descriptor calls and ~1.5 us
    through ``object.__setattr__`` (docs/decisions.md, issue 10 speed).
    """

    __slots__ = CanPacket.__slots__


@dataclass(frozen=True, slots=True)
class TxResultPacket:
    """A TX_RESULT packet (chapter 10): the outcome of frame ``ref_frame_index`` (counting KIND 0
    packets from 0) of the RxPDO image committed with sequence ``ref_packet_seq``."""

    channel: int
    ref_packet_seq: int
    ref_frame_index: int
    result: TxResultCode
    # The control word (CH and KIND 1, chapter 10) and the 6 bytes on the wire: encoding joins them.
    ctrl: int = field(init=False, repr=False, compare=False, default=0)
    _wire: bytes = field(init=False, repr=False, compare=False, default=b"")

    def __init__(self, channel: int, ref_packet_seq: int, ref_frame_index: int, result: TxResultCode) -> None:
        # Written out like CanPacket.__init__: checked, then stored on a draft and frozen.
        if type(channel) is not int or not 0 <= channel <= 7:
            raise _refuse(PdoError.INVALID_CHANNEL, f"channel {channel!r} does not fit CH (0..7, chapter 8)")
        seq, index = ref_packet_seq, ref_frame_index
        if not isinstance(seq, int) or not isinstance(index, int) or not 0 <= seq <= 0xFFFF or not 0 <= index <= 0xFF:
            raise _refuse(PdoError.UNKNOWN_KIND, "RefPacketSeq is u16, RefFrameIndex u8 (10)")
        if type(result) is not TxResultCode:
            if result not in _RESULT_VALUES:
                raise _refuse(PdoError.UNKNOWN_KIND, f"ResultCode {result!r} is not 0..5 (10)")
            result = TxResultCode(result)
        ctrl = channel | 1 << 13
        me: Any = self
        _set_class(me, "__class__", _TxResultDraft)
        me.channel = channel
        me.ref_packet_seq = seq
        me.ref_frame_index = index
        me.result = result
        me.ctrl = ctrl
        me._wire = _TX_RESULT.pack(ctrl, seq, index, result)
        me.__class__ = TxResultPacket

    @property
    def kind(self) -> PacketKind:
        """KIND 1."""
        return PacketKind.TX_RESULT


class _TxResultDraft:
    """A TxResultPacket under construction (see :class:`_CanPacketDraft`)."""

    __slots__ = TxResultPacket.__slots__


Packet = CanPacket | TxResultPacket
_RESULT_CODES = tuple(TxResultCode)
_PACKET_TYPES = (CanPacket, TxResultPacket)
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


def _ctrl_refusal(ctrl: int, layout: StreamLayout) -> StreamEncodeError | None:
    """Why ``layout`` refuses a packet with this control word, by the receiver's own rules
    (:func:`_ctrl_error`); an accepted one is learnt (:func:`_learn_ctrl`)."""
    code, why = _ctrl_error(ctrl, layout)
    if code:
        return _refuse(code, why)
    _learn_ctrl(ctrl, layout)
    return None


def _learn_ctrl(ctrl: int, layout: StreamLayout) -> _Geometry:
    """Cache the geometry of a control word :func:`_ctrl_error` accepted in ``layout``."""
    g = layout._geo[ctrl] = _ctrl_geometry(ctrl, layout)
    if not ctrl & _TSF_FULL64_OR_KIND:
        layout._plain.add(ctrl)
    return g


def _schedule_refusal() -> StreamEncodeError:
    return _refuse(PdoError.BAD_SCHEDULE, "TSF_FULL64 is the reservation format in the RxPDO and a timestamp in the "
                                          "TxPDO (8.4)")


def packet_size(packet: Packet, layout: StreamLayout) -> int:
    """Bytes ``packet`` occupies in ``layout``'s frame area, ALIGN4 padding included (8.3).

    Raises :class:`StreamEncodeError` for a packet this layout cannot carry.
    """
    if type(packet) is not CanPacket and type(packet) is not TxResultPacket:
        raise LocalError(f"not a packet: {packet!r}")
    ctrl = packet.ctrl
    if ctrl not in layout._geo:
        refusal = _ctrl_refusal(ctrl, layout)
        if refusal is not None:
            raise refusal
    if ctrl & _TSF_FULL64 == _TSF_FULL64 and packet.scheduled != layout._schedule_ok:  # type: ignore[union-attr]
        raise _schedule_refusal()
    raw = len(packet._wire)
    return (raw + 3) & ~3 if layout._align4 else raw


def encode_into(buf: bytearray | memoryview, layout: StreamLayout, seq: int, packets: Sequence[Packet], *,
                status_words: Sequence[int] = (0, 0, 0, 0), flags: HeaderFlags | int = 0,
                overflow_sat: int = 0) -> int:
    """Write one committed image into ``buf`` (``layout.pdo_bytes`` long); returns payload_len.

    Order of 5.4.4.1 step 4: packets from offset 24, the rest of the frame area zeroed (left as it
    is with PAYLOAD_ONLY_ENABLE, whose receivers ignore it, 9.1), header, seq_end last.
    TX_RESULT_PRESENT is set when a TX_RESULT is among ``packets``; ``overflow_sat`` saturates.
    Nothing is written when a packet is refused (:class:`StreamEncodeError`: the first control
    word, in stream order, the layout refuses; then TSF_FULL64 packets of the wrong direction).
    """
    if len(buf) != layout.pdo_bytes:
        raise LocalError(f"image buffer is {len(buf)} bytes, the layout needs {layout.pdo_bytes}")
    if len(packets) > MAX_FRAME_COUNT:
        raise _refuse(PdoError.PACKET_OVERRUN, f"{len(packets)} packets; frame_count holds at most 255")
    if len(status_words) != 4:
        raise LocalError("four channel status words (chapter 7)")
    # Each distinct control word is judged once per layout (cached in the layout, shared with
    # the decoder); a packet packed its own bytes when it was built, so writing is one join.
    try:
        ctrls = {p.ctrl for p in packets}
        wires = [p._wire for p in packets]
    except AttributeError:
        bad = next((p for p in packets if not (isinstance(p, _PACKET_TYPES) and hasattr(p, "_wire"))), None)
        raise LocalError(f"not a packet: {bad!r}") from None
    flags = int(flags) & 0x3F
    if not ctrls <= layout._plain:
        flags |= _judge_ctrls(ctrls, packets, layout)
    blob = b"".join([w + _ZERO_PAD[:-len(w) & 3] for w in wires] if layout._align4 else wires)
    end = layout.pdo_bytes
    off = HEADER_SIZE + len(blob)
    if off > end:
        raise _refuse(PdoError.PACKET_OVERRUN, f"packets need {off - HEADER_SIZE} bytes, the frame area has "
                                               f"{end - HEADER_SIZE} (chapter 12)")
    buf[HEADER_SIZE:off] = blob
    if not layout.options & Option.PAYLOAD_ONLY_ENABLE:
        buf[off:end] = bytes(end - off)
    payload_len = off - HEADER_SIZE
    if layout._crc:
        crc = binascii.crc_hqx(blob, 0xFFFF)
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


def _judge_ctrls(ctrls: set[int], packets: Sequence[Packet], layout: StreamLayout) -> int:
    """Check what the plain-control-word set does not cover: control words not seen yet in
    ``layout`` (refused in stream order), TSF_FULL64 (reservation in the RxPDO, timestamp in the
    TxPDO, 8.4) and TX_RESULT; returns TX_RESULT_PRESENT if one is there (chapter 6)."""
    geo = layout._geo
    if not geo.keys() >= ctrls:
        for p in packets:
            if p.ctrl not in geo:
                refusal = _ctrl_refusal(p.ctrl, layout)
                if refusal is not None:
                    raise refusal
    flags = 0
    full64 = set()
    for ctrl in ctrls - layout._plain:
        if ctrl & 0x6000:
            flags = 0x04    # HeaderFlags.TX_RESULT_PRESENT
        else:
            full64.add(ctrl)
    if full64:
        schedule_ok = layout._schedule_ok
        for p in packets:
            if p.ctrl in full64 and p.scheduled != schedule_ok:  # type: ignore[union-attr]
                raise _schedule_refusal()
    return flags


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
    # One copy of the image (bytes, so no view pins the caller's buffer) with a zero tail.
    data = b"".join((image, _DECODE_TAIL))
    packets: list[Packet] = []
    append = packets.append
    geo = layout._geo
    new = _new_object
    draft = _CanPacketDraft
    final = CanPacket
    u16 = _U16.unpack_from
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
            g = _learn_ctrl(ctrl, layout)
        unpack, shape, raw, step, head, n, ch, tsf, ide, fdf, brs, rtr, esi, d64, dlc, reserved, id_mask, aux_shift, \
            tail = g
        pend = off + raw
        nxt = off + step
        if nxt > end:
            raise fail(PdoError.TRUNCATED, "TX_RESULT cut by payload_len (10)" if shape == 3 else
                       f"packet ends at {nxt} beyond payload end {end} (8.3)", off, nxt, ctrl)
        if shape == 0:
            word = unpack(data, off)[1]
            stamp = offset_ns = tag = 0
        elif shape == 1:
            _c, word, stamp = unpack(data, off)
            offset_ns = tag = 0
        elif shape == 2:    # RxPDO: TSF_FULL64 is only the reservation format (8.4)
            _c, word, fmt, sflags, tag, offset_ns = unpack(data, off)
            if fmt != 1 or sflags:
                raise fail(PdoError.BAD_SCHEDULE, f"reservation format {fmt} flags {sflags}, expected 1 / 0 "
                                                  "(8.4)", off, nxt, ctrl)
            stamp = 0
        else:               # TX_RESULT (checked by _ctrl_error: KIND 1 allowed here)
            _c, ref_seq, ref_index, result = unpack(data, off)
            if result > 5:
                raise fail(PdoError.UNKNOWN_KIND, f"ResultCode {result} undefined (10)", off, nxt, ctrl)
            if nxt != pend and data[pend] | data[pend + 1]:
                raise fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", off, nxt, ctrl)
            txr: Any = new(_TxResultDraft)
            txr.channel = ch
            txr.ref_packet_seq = ref_seq
            txr.ref_frame_index = ref_index
            txr.result = _RESULT_CODES[result]
            txr.ctrl = ctrl
            txr._wire = data[off:pend]
            txr.__class__ = TxResultPacket
            append(txr)
            off = nxt
            continue
        if word & reserved:
            raise fail(PdoError.RESERVED_BIT, "StdIdField bits 14/15 must be 0 (8.1)", off, nxt, ctrl)
        if nxt != pend and data[pend:nxt].count(0) != nxt - pend:
            raise fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", off, nxt, ctrl)
        # The packet, slot by slot on a draft, then frozen (checked above; no __init__ round).
        head += off
        pkt: Any = new(draft)
        pkt.channel = ch
        pkt.can_id = word & id_mask
        pkt.extended = ide
        pkt.fd = fdf
        pkt.brs = brs
        pkt.rtr = rtr
        pkt.esi = esi
        pkt.data = data[head:head + n]
        pkt.tsf = tsf
        pkt.timestamp = stamp
        pkt.scheduled = shape == 2
        pkt.offset_ns = offset_ns
        pkt.tag = tag
        pkt.id_aux = word >> aux_shift
        pkt.d64 = d64
        pkt.dlc = dlc
        pkt.ctrl = ctrl
        pkt.raw_size = raw
        # a D64 window's tail is written 0 whatever the sender left there (8.1, 8.3)
        pkt._wire = data[off:pend] if not tail else data[off:head + n] + _ZERO_PAD[:tail]
        pkt.__class__ = final
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


def _ctrl_geometry(ctrl: int, layout: StreamLayout) -> _Geometry:
    """What the decoder needs of a control word that passed :func:`_ctrl_error` in ``layout`` (8.1-8.4):
    (head unpack, shape (0 plain, 1 timestamp, 2 reservation, 3 TX_RESULT), raw packet bytes,
    bytes to the next packet (ALIGN4), head bytes, data bytes of the frame, CH, TSF, IDE, FDF, BRS,
    RTR, ESI, D64, DLC, reserved id bits, id mask, ID_AUX shift, D64 window tail bytes)."""
    align4 = layout._align4
    if ctrl >> 13 & 3:
        return (_TX_RESULT.unpack_from, 3, 6, 8 if align4 else 6, 6, 0, ctrl & 7, Tsf.NONE, False, False, False,
                False, False, False, -1, 0, 0, 0, 0)
    dlc = ctrl >> 3 & 15
    ide = ctrl & 0x80 != 0
    fdf = ctrl & 0x100 != 0
    x = ctrl & 0x400 != 0
    rtr = x and not fdf
    d64 = ctrl >= 0x8000
    tsf = _TSFS[ctrl >> 11 & 3]
    shape = 0 if not tsf else 2 if layout._schedule_ok else 1
    n = 0 if rtr else FD_DLC_TO_LEN[dlc]
    head = (6 if ide else 4) + _TSF_BYTES[tsf]
    raw = head + (64 if d64 else n)
    return (_PACKET_HEADS[ide][4 if shape == 2 else tsf].unpack_from, shape, raw, (raw + 3) & ~3 if align4 else raw,
            head, n, ctrl & 7, tsf, ide, fdf, ctrl & 0x200 != 0, rtr, x and fdf, d64, dlc, 0 if ide else 0xC000,
            0x1FFFFFFF if ide else 0x7FF, 29 if ide else 11, 64 - n if d64 else 0)
