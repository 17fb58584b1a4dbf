"""The ECAN-Lite frame-stream format (manual chapters 6-10, 13.2, 13.8): its constants, the enums of
its fields and objects, the small pure functions every side of the stream shares (CRC, profile
word, layout id, sequence, timestamps, profile checks) and the two errors (:class:`StreamError`
for an image a receiver rejects, :class:`StreamEncodeError` for a packet a sender cannot put in).
"""

from __future__ import annotations

import binascii
import enum
import struct
from dataclasses import dataclass
from typing import Final

from gatewaylab.bus.frame import FD_DLC_TO_LEN
from gatewaylab.common.errors import LocalError, ProtocolError

__all__ = [
    "COMMIT",
    "CRC_ALG_CCITT_FALSE",
    "DEFAULT_FEATURES",
    "HEADER",
    "HEADER_SEQ_END",
    "HEADER_SIZE",
    "MAX_CHANNELS",
    "MAX_FRAME_COUNT",
    "NO_FLAGS",
    "OPTION_MASK",
    "PACKET_HEADS",
    "PROFILE_MASK",
    "TIMESTAMP_UNIT_S",
    "TSFS",
    "TSF_BYTES",
    "TX_RESULT",
    "U16",
    "VER_IHL",
    "ZERO_PAD",
    "Commit",
    "Direction",
    "Feature",
    "HeaderFlags",
    "Option",
    "PacketKind",
    "ParseDiag",
    "PdoError",
    "ProfileStatus",
    "StreamEncodeError",
    "StreamError",
    "Tsf",
    "TxResultCode",
    "check_layout",
    "check_options",
    "crc16",
    "dlc_to_len",
    "fold_layout_id",
    "next_seq",
    "profile_word",
    "saturate_u8",
    "timestamp_ticks",
]


# (Constants are Final: compiled, mypyc reads them natively, not from the module's dict.)
#: ver_ihl: version 1 in the high nibble, 6 four-byte words in the low nibble (chapter 6).
VER_IHL: Final = 0x16
HEADER_SIZE: Final = 24
#: crc_alg value for CRC-16/CCITT-FALSE (chapter 6); 0 with NO_CRC16_ENABLE (9.1).
CRC_ALG_CCITT_FALSE: Final = 1
#: 0xF000:14 Max CAN channels.
MAX_CHANNELS: Final = 4
#: frame_count is one byte (chapter 6).
MAX_FRAME_COUNT: Final = 255
#: 0xF000:12 Encapsulation profile mask: profiles 0, 1, 4, 5.
PROFILE_MASK: Final = 0x33
#: 0xF000:15 PDO option flags mask.
OPTION_MASK: Final = 0x1F
#: One tick of delta16/delta32/full64 timestamps (8.4 gives no unit; docs/decisions.md).
TIMESTAMP_UNIT_S: Final = 1e-6


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


NO_FLAGS = HeaderFlags(0)

#: 0xF000:16 default 0x00001F3B (13.8): no delta32, no stream CRC32.
DEFAULT_FEATURES: Final = 0x1F3B


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


#: (A tuple of any length to mypy: compiled, a fixed-length tuple indexed by a variable is boxed first.)
TSF_BYTES: Final[tuple[int, ...]] = (0, 2, 4, 8)
TSFS: Final = tuple(Tsf)
HEADER: Final = struct.Struct("<BBHHHHHBBBB4H")
HEADER_SEQ_END: Final = struct.Struct("<H")
U16: Final = struct.Struct("<H")
COMMIT: Final = struct.Struct("<HHHH")
TX_RESULT: Final = struct.Struct("<HHBB")
#: A CAN_FRAME's control word, id field and timestamp field in one format (8.1, 8.4), by
#: [IDE][shape]: shape 0 no timestamp, 1 delta16, 2 delta32, 3 full64, 4 the RxPDO reservation
#: (format u8, flags u8, tag u16, offset_ns u32). The packet packs its head with these; the
#: decoder reads the same fields by indexing its bytes (compiled: native ints, docs/performance.md).
PACKET_HEADS: Final = tuple(tuple(struct.Struct("<H" + id_fmt + ts_fmt) for ts_fmt in ("", "H", "I", "Q", "BBHI"))
                     for id_fmt in ("H", "I"))
#: Zeros for a D64 window tail (< 64) plus ALIGN4 padding (< 4).
ZERO_PAD: Final = bytes(68)


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

