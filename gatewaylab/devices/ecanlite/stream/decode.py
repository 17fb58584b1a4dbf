"""The frame-stream decoder (manual chapters 6, 8-10, 13.2, 13.8): images into packets.

:func:`commit_state` tells a new image from an idempotent repeat and from a torn one (6.1);
:func:`decode_stream` checks header and packets in the order of 6.1 and raises
:class:`StreamError` with the LastPDOError code of 13.2 and a parse diagnostic (16.2); it never
raises anything else, whatever the bytes. Each packet's control word is checked against the
layout where it is read (one test for the common case, :func:`~.layout.ctrl_error` for the rest);
its frame is a :class:`~gatewaylab.bus.frame.CanFrame`, which checks its own fields.
"""

from __future__ import annotations

import binascii
from typing import TYPE_CHECKING, Final

from gatewaylab.bus.frame import FD_DLC_TO_LEN, CanFrame
from gatewaylab.devices.ecanlite.stream.format import (
    COMMIT,
    CRC_ALG_CCITT_FALSE,
    HEADER_SIZE,
    TSF_BYTES,
    TSFS,
    U16,
    VER_IHL,
    ZERO_PAD,
    Commit,
    HeaderFlags,
    ParseDiag,
    PdoError,
    StreamError,
    TxResultCode,
)
from gatewaylab.devices.ecanlite.stream.layout import StreamLayout, ctrl_error
from gatewaylab.devices.ecanlite.stream.packets import (
    CanPacket,
    DecodedStream,
    Packet,
    StreamHeader,
    TxResultPacket,
)

if TYPE_CHECKING:
    from mypy_extensions import i64  # compiled: a machine integer; pure Python never evaluates it

__all__ = ["commit_state", "decode_stream"]


#: Appended to the decoder's copy of an image, so a packet head can be read before the check
#: that it ends inside payload_len (a full64 head is 2 + 4 + 8 bytes).
_DECODE_TAIL: Final = bytes(16)
_RESULT_CODES: Final = tuple(TxResultCode)
#: header_flags bits 0-5 by value (an enum call per image costs ~1 us).
_HEADER_FLAGS: Final = tuple(HeaderFlags(v) for v in range(64))


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
    seq_begin, seq_end, payload_len, crc = COMMIT.unpack_from(image, 2)
    if seq_begin != seq_end:
        return Commit.TORN
    if previous is None or len(previous) < HEADER_SIZE or U16.unpack_from(previous, 2)[0] != seq_begin:
        return Commit.NEW
    n = HEADER_SIZE + payload_len
    if bytes(image[:n]) == bytes(previous[:n]):
        return Commit.SAME
    if image[15] == CRC_ALG_CCITT_FALSE and n <= len(image) and binascii.crc_hqx(image[HEADER_SIZE:n], 0xFFFF) != crc:
        return Commit.TORN
    return Commit.DUPLICATE


def _fail(code: PdoError, reason: str, seq: int, payload_len: int, crc: int, layout_id: int, offset: int = -1,
          packet_end: int = -1, ctrl: int = -1) -> StreamError:
    """The StreamError of a parse failure with its parse_diag (16.2): header fields, where, the control word.
    (A module function, not a closure: compiled, a closure puts the captured locals in an object.)"""
    if ctrl < 0:
        return StreamError(code, ParseDiag(offset, packet_end, -1, seq, payload_len, crc, layout_id, reason=reason))
    return StreamError(code, ParseDiag(offset, packet_end, ctrl, seq, payload_len, crc, layout_id,
                                       ctrl & 7, ctrl >> 3 & 15, ctrl >> 11 & 3, ctrl >> 13 & 3, reason))


def _u16(data: bytes, off: int) -> int:
    """The little-endian u16 at ``off`` (compiled: byte indexing of ``bytes`` is native)."""
    return data[off] | data[off + 1] << 8


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
    # One copy of the image (bytes: no view pins the caller's buffer, and compiled, ``data[i]`` is a
    # native int) with a zero tail, so a packet head can be read before the check that it ends
    # inside payload_len (a full64 head is 2 + 4 + 8 bytes).
    data = b"".join((image, _DECODE_TAIL))
    ver_ihl = data[0]
    seq = _u16(data, 2)
    seq_end = _u16(data, 4)
    payload_len = _u16(data, 6)
    crc = _u16(data, 8)
    layout_id = _u16(data, 10)
    mask = data[12]
    crc_alg = data[15]
    if ver_ihl != VER_IHL:
        raise _fail(PdoError.BAD_HEADER, f"ver_ihl 0x{ver_ihl:02X}, expected 0x16 (chapter 6)",
                    seq, payload_len, crc, layout_id)
    if seq != seq_end:
        raise _fail(PdoError.BAD_HEADER, f"torn image: seq_begin {seq} != seq_end {seq_end} (6.1)",
                    seq, payload_len, crc, layout_id)
    if layout.crc_enabled:
        if crc_alg != CRC_ALG_CCITT_FALSE:
            raise _fail(PdoError.BAD_HEADER, f"crc_alg {crc_alg}, expected 1 (6.1)", seq, payload_len, crc, layout_id)
    elif crc_alg != 0 or crc != 0:
        raise _fail(PdoError.BAD_HEADER, f"crc_alg {crc_alg} / crc 0x{crc:04X}, NO_CRC16 expects 0 / 0 (9.1)",
                    seq, payload_len, crc, layout_id)
    end = HEADER_SIZE + payload_len
    if end > size:
        raise _fail(PdoError.PACKET_OVERRUN, f"payload_len {payload_len} > frame area {size - HEADER_SIZE} (6.1)",
                    seq, payload_len, crc, layout_id)
    if layout.crc_enabled:
        calc = binascii.crc_hqx(memoryview(data)[HEADER_SIZE:end], 0xFFFF)   # (a view of our own copy)
        if calc != crc:
            raise _fail(PdoError.BAD_CRC, f"payload_crc16 0x{crc:04X} != 0x{calc:04X} (6.1)",
                        seq, payload_len, crc, layout_id)
    if layout_id != layout.layout_id or mask != layout.channel_mask:
        raise _fail(PdoError.ACTIVE_AREA, f"layout_id 0x{layout_id:04X} / channel_mask 0x{mask:02X}, active "
                                          f"0x{layout.layout_id:04X} / 0x{layout.channel_mask:02X} (5.4.4.1)",
                    seq, payload_len, crc, layout_id)
    packets = _decode_packets(data, end, layout, seq, payload_len, crc, layout_id)
    count = data[13]
    if len(packets) != count:
        raise _fail(PdoError.BAD_HEADER, f"frame_count {count} but {len(packets)} packets in payload_len (6)",
                    seq, payload_len, crc, layout_id, end)
    header = StreamHeader(_HEADER_FLAGS[data[1] & 0x3F], seq, seq_end, payload_len, crc, layout_id, mask, count,
                          data[14], crc_alg, (_u16(data, 16), _u16(data, 18), _u16(data, 20), _u16(data, 22)),
                          ver_ihl)
    return DecodedStream(header, tuple(packets))


def _decode_packets(data: bytes, end: int, layout: StreamLayout, seq: int, payload_len: int, crc: int,
                    layout_id: int) -> list[Packet]:
    """The packets of ``data[24:end]`` (chapter 8), each checked where it is read.

    Fields are read by indexing ``data`` (compiled: native ints, no tuple per packet; the locals
    typed ``i64`` are machine words, no tagged-int checks), and the packet is built from values
    already checked (its CanFrame checks its own fields)."""
    packets: list[Packet] = []
    chmask: i64 = layout.channel_mask & 0x0F
    tsf_mask: i64 = layout.tsf_mask
    # KIND bits, and D64 where the layout has no D64 windows: any of them set needs the full verdict
    refused: i64 = 0x6000 if layout.d64_allowed else 0xE000
    schedule = layout.schedule_allowed
    align4 = layout.align4
    lengths = FD_DLC_TO_LEN
    tsfs = TSFS
    tsf_bytes = TSF_BYTES
    stop: i64 = end
    off: i64 = HEADER_SIZE
    while off < stop:
        if off + 2 > end:
            raise _fail(PdoError.TRUNCATED, "control word cut by payload_len (8)", seq, payload_len, crc, layout_id,
                        off, off + 2)
        ctrl: i64 = data[off] | data[off + 1] << 8
        dlc: i64 = ctrl >> 3 & 15
        fdf = ctrl & 0x100 != 0
        tsf: i64 = ctrl >> 11 & 3
        # the common case in one test: KIND 0, channel in the mask, classic rules (8.2), TSF and
        # D64 allowed here; anything else gets the receiver's full verdict
        if (ctrl & refused or not chmask >> (ctrl & 7) & 1 or not tsf_mask >> tsf & 1
                or (not fdf and (dlc > 8 or ctrl & 0x8200))):
            code, why = ctrl_error(ctrl, layout)
            if code:
                raise _fail(code, why, seq, payload_len, crc, layout_id, off, -1, ctrl)
            # only a TX_RESULT passes ctrl_error here (KIND 1 allowed, chapter 10)
            nxt: i64 = off + (8 if align4 else 6)
            if nxt > end:
                raise _fail(PdoError.TRUNCATED, "TX_RESULT cut by payload_len (10)", seq, payload_len, crc,
                            layout_id, off, nxt, ctrl)
            result = data[off + 5]
            if result > 5:
                raise _fail(PdoError.UNKNOWN_KIND, f"ResultCode {result} undefined (10)", seq, payload_len, crc,
                            layout_id, off, nxt, ctrl)
            if align4 and data[off + 6] | data[off + 7]:
                raise _fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", seq, payload_len, crc,
                            layout_id, off, nxt, ctrl)
            packets.append(TxResultPacket(ctrl & 7, data[off + 2] | data[off + 3] << 8, data[off + 4],
                                          _RESULT_CODES[result]))
            off = nxt
            continue
        ide = ctrl & 0x80 != 0
        x = ctrl & 0x400 != 0
        rtr = x and not fdf
        d64 = ctrl >= 0x8000
        n: i64 = 0 if rtr else dlc if dlc <= 8 else lengths[dlc]
        head: i64 = (6 if ide else 4) + (tsf_bytes[tsf] if tsf else 0)
        raw: i64 = head + (64 if d64 else n)
        nxt = off + ((raw + 3) & ~3 if align4 else raw)
        if nxt > stop:
            raise _fail(PdoError.TRUNCATED, f"packet ends at {nxt} beyond payload end {end} (8.3)", seq,
                        payload_len, crc, layout_id, off, nxt, ctrl)
        at: i64 = off + 2
        word: i64
        if ide:
            word = data[at] | data[at + 1] << 8 | data[at + 2] << 16 | data[at + 3] << 24
            at += 4
        else:
            word = data[at] | data[at + 1] << 8
            at += 2
        stamp = offset_ns = tag = 0
        scheduled = False
        if tsf:
            if tsf == 1:
                stamp = data[at] | data[at + 1] << 8
            elif tsf == 2:
                stamp = data[at] | data[at + 1] << 8 | data[at + 2] << 16 | data[at + 3] << 24
            elif not schedule:
                stamp = int.from_bytes(data[at:at + 8], "little")
            else:           # RxPDO: TSF_FULL64 is only the reservation format (8.4)
                fmt = data[at]
                sflags = data[at + 1]
                if fmt != 1 or sflags:
                    raise _fail(PdoError.BAD_SCHEDULE, f"reservation format {fmt} flags {sflags}, expected 1 / 0 "
                                                       "(8.4)", seq, payload_len, crc, layout_id, off, nxt, ctrl)
                tag = data[at + 2] | data[at + 3] << 8
                offset_ns = data[at + 4] | data[at + 5] << 8 | data[at + 6] << 16 | data[at + 7] << 24
                scheduled = True
        if not ide and word & 0xC000:
            raise _fail(PdoError.RESERVED_BIT, "StdIdField bits 14/15 must be 0 (8.1)", seq, payload_len, crc,
                        layout_id, off, nxt, ctrl)
        pend: i64 = off + raw
        pad: i64 = pend
        while pad < nxt:    # ALIGN4 padding (8.3)
            if data[pad]:
                raise _fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", seq, payload_len, crc,
                            layout_id, off, nxt, ctrl)
            pad += 1
        start: i64 = off + head
        payload = data[start:start + n]
        if ide:
            frame = CanFrame(word & 0x1FFFFFFF, payload, True, rtr, fdf, ctrl & 0x200 != 0, x and fdf,
                             dlc if rtr else -1)
        elif rtr or fdf:
            frame = CanFrame(word & 0x7FF, payload, False, rtr, fdf, ctrl & 0x200 != 0, x and fdf,
                             dlc if rtr else -1)
        else:
            frame = CanFrame(word & 0x7FF, payload)
        # a D64 window's tail is written 0 whatever the sender left there (8.1, 8.3)
        wire = data[off:pend] if not d64 else data[off:start + n] + ZERO_PAD[:64 - n]
        packets.append(CanPacket(ctrl & 7, frame, tsfs[tsf], stamp, scheduled, offset_ns, tag,
                                 word >> (29 if ide else 11), d64, ctrl=ctrl, wire=wire))
        off = nxt
    return packets
