"""One direction's active profile (manual chapter 9, 13.2 profile word, 13.8 feature flags): what an
image of that direction looks like and what its packets may carry. A frozen value; what it
allows is derived once when it is made, never learnt while it is used.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import Final

from gatewaylab.common.errors import LocalError
from gatewaylab.devices.ecanlite.budget import BudgetPolicy
from gatewaylab.devices.ecanlite.stream.format import (
    DEFAULT_FEATURES,
    HEADER_SIZE,
    MAX_CHANNELS,
    Direction,
    Feature,
    Option,
    PacketKind,
    PdoError,
    ProfileStatus,
    Tsf,
    check_layout,
    fold_layout_id,
    profile_word,
)

__all__ = ["StreamLayout", "ctrl_error"]


_LAYOUT_CRC: Final = struct.Struct("<IHH")


@dataclass(frozen=True, slots=True)
class StreamLayout:
    """One direction's active profile (0x8010 or 0x8011 after apply): what an image looks like.

    ``direction`` is not part of the profile word but decides what packets may appear (8.4,
    chapter 10): the device's RxPDO layout is ``Direction.RX``, its TxPDO layout ``Direction.TX``.
    ``features`` is 0xF000:16; tests raise it to exercise capabilities the product leaves off.
    The fields after ``features`` are derived from the others when the layout is made.
    """

    multiplier: int = 8
    channel_mask: int = 0x0F
    profile: int = 0
    #: 0x8010/0x8011:06 as an integer (a BudgetPolicy compares equal). Not made a BudgetPolicy here: a
    #: compiled (mypyc) ``int`` attribute stores a machine integer, the enum would not survive.
    budget_policy: int = BudgetPolicy.BALANCED
    options: int = 0
    direction: Direction = Direction.RX
    features: int = DEFAULT_FEATURES
    #: Bit ``tsf`` set: a CAN_FRAME may carry that TSF here (chapter 9 profiles, 8.4 directions).
    tsf_mask: int = field(init=False, repr=False, compare=False, default=0)
    #: D64 windows allowed (profiles 4/5 with the D64 feature, 9).
    d64_allowed: bool = field(init=False, repr=False, compare=False, default=False)
    #: TX_RESULT packets allowed (TxPDO with TX_RESULT_ENABLE and the feature, chapter 10).
    tx_result_allowed: bool = field(init=False, repr=False, compare=False, default=False)
    #: TSF_FULL64 is the scheduled-transmit reservation (RxPDO with RX_TSF_SCHEDULE_TX, 8.4).
    schedule_allowed: bool = field(init=False, repr=False, compare=False, default=False)
    #: ALIGN_4_ENABLE: packets padded to 4 bytes, padding counted in payload_len (8.3).
    align4: bool = field(init=False, repr=False, compare=False, default=False)
    #: payload_crc16 in use (crc_alg 1) unless NO_CRC16_ENABLE (9.1).
    crc_enabled: bool = field(init=False, repr=False, compare=False, default=True)

    def __post_init__(self) -> None:
        status = check_layout(self.multiplier, self.channel_mask, self.profile, int(self.budget_policy),
                              self.options)
        if status is not ProfileStatus.OK:
            raise LocalError(f"not an ECAN-Lite layout ({status.name}): {self!r}")
        derive = object.__setattr__
        feat = self.features
        tx = self.direction is Direction.TX
        tsf_mask = 1 << Tsf.NONE
        if tx and self.profile in (1, 5):
            for tsf, bit in ((Tsf.DELTA16, Feature.TSF_DELTA16), (Tsf.DELTA32, Feature.TSF_DELTA32),
                             (Tsf.FULL64, Feature.TSF_FULL64)):
                if feat & bit:
                    tsf_mask |= 1 << tsf
        schedule = not tx and bool(feat & Feature.RX_TSF_SCHEDULE_TX)
        if schedule:
            tsf_mask |= 1 << Tsf.FULL64
        derive(self, "tsf_mask", tsf_mask)
        derive(self, "schedule_allowed", schedule)
        derive(self, "d64_allowed", self.profile in (4, 5) and bool(feat & Feature.D64))
        derive(self, "tx_result_allowed",
               tx and bool(self.options & Option.TX_RESULT_ENABLE) and bool(feat & Feature.TX_RESULT))
        derive(self, "align4", bool(self.options & Option.ALIGN_4_ENABLE))
        derive(self, "crc_enabled", not self.options & Option.NO_CRC16_ENABLE)

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
    def channels(self) -> tuple[int, ...]:
        """The enabled channels of this direction, ascending."""
        return tuple(ch for ch in range(MAX_CHANNELS) if self.channel_mask >> ch & 1)

    def allows_tsf(self, tsf: Tsf | int) -> bool:
        """Whether a CAN_FRAME may carry this TSF here (chapter 9 profiles, 8.4 directions)."""
        return bool(self.tsf_mask >> tsf & 1)


#: Control-word bits a TX_RESULT leaves 0: DLC, IDE, FDF, BRS, X, TSF, D64 (chapter 10: CH + KIND).
_TX_RESULT_CTRL_ZERO: Final = 0x9FF8


def ctrl_error(ctrl: int, layout: StreamLayout) -> tuple[PdoError, str]:
    """The LastPDOError a control word alone earns in ``layout`` (chapter 8, 8.2, 8.4, 9, 10):
    the receiver's rule, which the encoder applies too before it writes anything."""
    kind = ctrl >> 13 & 3
    ch = ctrl & 7
    if kind and (kind != PacketKind.TX_RESULT or not layout.tx_result_allowed):
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
    if d64 and not layout.d64_allowed:
        return PdoError.FRAME_OVERRUN, f"D64 window not allowed in profile {layout.profile} (9)"
    tsf = ctrl >> 11 & 3
    if not layout.tsf_mask >> tsf & 1:
        if layout.direction is Direction.RX and tsf == Tsf.FULL64:
            return PdoError.BAD_SCHEDULE, "scheduled transmit (RX_TSF_SCHEDULE_TX) not supported (8.4)"
        return PdoError.INVALID_TSF, f"TSF {tsf} not allowed in this profile/direction (8.4, 9)"
    return PdoError.OK, ""
