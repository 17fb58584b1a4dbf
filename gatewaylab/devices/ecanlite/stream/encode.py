"""The frame-stream encoder (manual 5.4.4.1, chapters 6, 8-10): packets into a committed image.

Every packet is judged by the receiver's own rules (:func:`~.layout.ctrl_error`) before a byte
is written; then the packets' own wire bytes are joined, the rest of the frame area zeroed, the
CRC computed and the header written with seq_end last (5.4.4.1 step 4).
"""

from __future__ import annotations

import binascii
from collections.abc import Sequence
from typing import TYPE_CHECKING, Final

from gatewaylab.common.errors import LocalError
from gatewaylab.devices.ecanlite.stream.format import (
    CRC_ALG_CCITT_FALSE,
    HEADER,
    HEADER_SEQ_END,
    HEADER_SIZE,
    MAX_FRAME_COUNT,
    VER_IHL,
    ZERO_PAD,
    HeaderFlags,
    Option,
    PdoError,
    StreamEncodeError,
    saturate_u8,
)
from gatewaylab.devices.ecanlite.stream.layout import StreamLayout, ctrl_error
from gatewaylab.devices.ecanlite.stream.packets import CanPacket, Packet, TxResultPacket, refuse

if TYPE_CHECKING:
    from mypy_extensions import i64  # compiled: a machine integer; pure Python never evaluates it

__all__ = ["encode_into", "encode_stream", "judge", "packet_size"]


#: Control-word TSF bits 11-12 both set: TSF_FULL64 (a TX_RESULT leaves them 0).
_TSF_FULL64: Final = 0x1800
#: (an int: compiled, ``int & Option.X`` goes through the enum's Python-level ``__rand__``)
_PAYLOAD_ONLY: Final = int(Option.PAYLOAD_ONLY_ENABLE)


def _schedule_refusal() -> StreamEncodeError:
    return refuse(PdoError.BAD_SCHEDULE, "TSF_FULL64 is the reservation format in the RxPDO and a timestamp in the "
                                         "TxPDO (8.4)")


def packet_size(packet: Packet, layout: StreamLayout) -> int:
    """Bytes ``packet`` occupies in ``layout``'s frame area, ALIGN4 padding included (8.3).

    Raises :class:`StreamEncodeError` for a packet this layout cannot carry.
    """
    if type(packet) is not CanPacket and type(packet) is not TxResultPacket:
        raise LocalError(f"not a packet: {packet!r}")
    ctrl = packet.ctrl
    code, why = ctrl_error(ctrl, layout)
    if code:
        raise refuse(code, why)
    if ctrl & _TSF_FULL64 == _TSF_FULL64 and packet.scheduled != layout.schedule_allowed:  # type: ignore[union-attr]
        raise _schedule_refusal()
    raw = len(packet.wire)
    return (raw + 3) & ~3 if layout.align4 else raw


def _first_foreign(items: Sequence[object]) -> object:
    """The first item that is not a packet (typed ``object``: compiled, a loop variable typed as a
    packet would fail its own type check on it)."""
    return next(p for p in items if type(p) is not CanPacket and type(p) is not TxResultPacket)


def judge(packets: Sequence[Packet], layout: StreamLayout) -> int:
    """Refuse what ``layout`` cannot carry before anything is written: the first control word it
    refuses in stream order, then a TSF_FULL64 packet of the wrong direction (reservation in the
    RxPDO, timestamp in the TxPDO, 8.4). Returns TX_RESULT_PRESENT when a TX_RESULT is there
    (chapter 6), else 0. One test per packet for the common case; the receiver's full verdict
    (:func:`~.layout.ctrl_error`) from the first packet that fails it."""
    chmask: i64 = layout.channel_mask & 0x0F
    tsf_mask: i64 = layout.tsf_mask
    # KIND bits, and D64 where the layout has no D64 windows: any of them set needs the full verdict
    refused: i64 = 0x6000 if layout.d64_allowed else 0xE000
    first: i64 = -1     # the first packet the common-case test does not clear
    kinds: i64 = 0      # every control word OR-ed: TSF_FULL64 bits, KIND bits
    try:
        for i, p in enumerate(packets):
            ctrl: i64 = p.ctrl
            kinds |= ctrl
            # the common case: KIND 0, channel in the mask, TSF allowed, no D64 or allowed (a
            # CanPacket's frame already obeys the CAN rules of 8.2)
            if first < 0 and (ctrl & refused or not chmask >> (ctrl & 7) & 1 or not tsf_mask >> (ctrl >> 11 & 3) & 1):
                first = i
    except (AttributeError, TypeError):   # compiled (mypyc), a non-packet fails the type check of p
        raise LocalError(f"not a packet: {_first_foreign(packets)!r}") from None
    if first >= 0:
        for p in packets[first:]:
            if type(p) is not CanPacket and type(p) is not TxResultPacket:
                raise LocalError(f"not a packet: {p!r}")
            code, why = ctrl_error(p.ctrl, layout)
            if code:
                raise refuse(code, why)
    if kinds & _TSF_FULL64 == _TSF_FULL64:      # some packet may be TSF_FULL64
        schedule = layout.schedule_allowed
        for p in packets:
            if p.ctrl & 0x7800 == _TSF_FULL64 and p.scheduled != schedule:  # type: ignore[union-attr]
                raise _schedule_refusal()
    # every control word passed: one with KIND bits set is a TX_RESULT (chapter 10)
    return int(HeaderFlags.TX_RESULT_PRESENT) if kinds & 0x6000 else 0


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
        raise refuse(PdoError.PACKET_OVERRUN, f"{len(packets)} packets; frame_count holds at most 255")
    if len(status_words) != 4:
        raise LocalError("four channel status words (chapter 7)")
    flags = int(flags) & 0x3F | judge(packets, layout)
    wires = [p.wire for p in packets]
    blob = b"".join([w + ZERO_PAD[:-len(w) & 3] for w in wires] if layout.align4 else wires)
    end = layout.pdo_bytes
    off = HEADER_SIZE + len(blob)
    if off > end:
        raise refuse(PdoError.PACKET_OVERRUN, f"packets need {off - HEADER_SIZE} bytes, the frame area has "
                                              f"{end - HEADER_SIZE} (chapter 12)")
    buf[HEADER_SIZE:off] = blob
    if not layout.options & _PAYLOAD_ONLY:
        buf[off:end] = bytes(end - off)
    payload_len = off - HEADER_SIZE
    if layout.crc_enabled:
        crc = binascii.crc_hqx(blob, 0xFFFF)
        alg = CRC_ALG_CCITT_FALSE
    else:
        crc = alg = 0
    seq &= 0xFFFF
    s0, s1, s2, s3 = status_words
    # seq_end (offset 4) is packed too but written again last, the commit of 5.4.4.1 step 4.
    HEADER.pack_into(buf, 0, VER_IHL, flags, seq, (seq - 1) & 0xFFFF, payload_len, crc, layout.layout_id,
                     layout.channel_mask, len(packets), saturate_u8(overflow_sat), alg,
                     s0 & 0xFFFF, s1 & 0xFFFF, s2 & 0xFFFF, s3 & 0xFFFF)
    HEADER_SEQ_END.pack_into(buf, 4, seq)
    return payload_len


def encode_stream(layout: StreamLayout, seq: int, packets: Sequence[Packet], *,
                  status_words: Sequence[int] = (0, 0, 0, 0), flags: HeaderFlags | int = 0,
                  overflow_sat: int = 0) -> bytes:
    """One committed image of exactly ``layout.pdo_bytes`` bytes, unused area zeroed (5.4.4.1)."""
    buf = bytearray(layout.pdo_bytes)
    encode_into(buf, layout, seq, packets, status_words=status_words, flags=flags, overflow_sat=overflow_sat)
    return bytes(buf)
