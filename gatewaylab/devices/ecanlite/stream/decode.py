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

from gatewaylab.bus.frame import FD_DLC_TO_LEN, CanFrame
from gatewaylab.devices.ecanlite.stream.format import (
    COMMIT,
    CRC_ALG_CCITT_FALSE,
    HEADER,
    HEADER_SIZE,
    PACKET_HEADS,
    TSF_BYTES,
    TSFS,
    TX_RESULT,
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
    DecodedStream,
    Packet,
    StreamHeader,
    TxResultPacket,
    decoded_packet,
)

#: Appended to the decoder's copy of an image, so a packet head can be unpacked before the check
#: that it ends inside payload_len (a full64 head is 2 + 4 + 8 bytes).
_DECODE_TAIL = bytes(16)
_RESULT_CODES = tuple(TxResultCode)
_TX_RESULT_UNPACK = TX_RESULT.unpack_from


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
     s0, s1, s2, s3) = HEADER.unpack_from(image, 0)

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
    if layout.crc_enabled:
        if crc_alg != CRC_ALG_CCITT_FALSE:
            raise fail(PdoError.BAD_HEADER, f"crc_alg {crc_alg}, expected 1 (6.1)")
    elif crc_alg != 0 or crc != 0:
        raise fail(PdoError.BAD_HEADER, f"crc_alg {crc_alg} / crc 0x{crc:04X}, NO_CRC16 expects 0 / 0 (9.1)")
    end = HEADER_SIZE + payload_len
    if end > size:
        raise fail(PdoError.PACKET_OVERRUN, f"payload_len {payload_len} > frame area {size - HEADER_SIZE} (6.1)")
    if layout.crc_enabled:
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
    chmask = layout.channel_mask & 0x0F
    tsf_mask = layout.tsf_mask
    d64_ok = layout.d64_allowed
    reservation = 4 if layout.schedule_allowed else 3
    align4 = layout.align4
    u16 = U16.unpack_from
    heads = PACKET_HEADS
    lengths = FD_DLC_TO_LEN
    tsfs = TSFS
    tsf_bytes = TSF_BYTES
    off = HEADER_SIZE
    while off < end:
        if off + 2 > end:
            raise fail(PdoError.TRUNCATED, "control word cut by payload_len (8)", off, off + 2)
        ctrl = u16(data, off)[0]
        dlc = ctrl >> 3 & 15
        fdf = ctrl & 0x100 != 0
        tsf = ctrl >> 11 & 3
        # the common case in one test: KIND 0, channel in the mask, classic rules (8.2), TSF and
        # D64 allowed here; anything else gets the receiver's full verdict
        if (ctrl & 0x6000 or not chmask >> (ctrl & 7) & 1 or not tsf_mask >> tsf & 1
                or (ctrl & 0x8000 and not d64_ok) or (not fdf and (dlc > 8 or ctrl & 0x8200))):
            code, why = ctrl_error(ctrl, layout)
            if code:
                raise fail(code, why, off, -1, ctrl)
            # only a TX_RESULT passes ctrl_error here (KIND 1 allowed, chapter 10)
            nxt = off + (8 if align4 else 6)
            if nxt > end:
                raise fail(PdoError.TRUNCATED, "TX_RESULT cut by payload_len (10)", off, nxt, ctrl)
            _c, ref_seq, ref_index, result = _TX_RESULT_UNPACK(data, off)
            if result > 5:
                raise fail(PdoError.UNKNOWN_KIND, f"ResultCode {result} undefined (10)", off, nxt, ctrl)
            if align4 and data[off + 6] | data[off + 7]:
                raise fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", off, nxt, ctrl)
            packets.append(TxResultPacket(ctrl & 7, ref_seq, ref_index, _RESULT_CODES[result]))
            off = nxt
            continue
        ide = ctrl & 0x80 != 0
        x = ctrl & 0x400 != 0
        rtr = x and not fdf
        d64 = ctrl >= 0x8000
        n = 0 if rtr else lengths[dlc]
        head = (6 if ide else 4) + tsf_bytes[tsf]
        raw = head + (64 if d64 else n)
        nxt = off + ((raw + 3) & ~3 if align4 else raw)
        if nxt > end:
            raise fail(PdoError.TRUNCATED, f"packet ends at {nxt} beyond payload end {end} (8.3)", off, nxt, ctrl)
        shape = reservation if tsf == 3 else tsf
        if shape == 0:
            word = heads[ide][0].unpack_from(data, off)[1]
            stamp = offset_ns = tag = 0
        elif shape != 4:
            _c, word, stamp = heads[ide][tsf].unpack_from(data, off)
            offset_ns = tag = 0
        else:               # RxPDO: TSF_FULL64 is only the reservation format (8.4)
            _c, word, fmt, sflags, tag, offset_ns = heads[ide][4].unpack_from(data, off)
            if fmt != 1 or sflags:
                raise fail(PdoError.BAD_SCHEDULE, f"reservation format {fmt} flags {sflags}, expected 1 / 0 "
                                                  "(8.4)", off, nxt, ctrl)
            stamp = 0
        if not ide and word & 0xC000:
            raise fail(PdoError.RESERVED_BIT, "StdIdField bits 14/15 must be 0 (8.1)", off, nxt, ctrl)
        pend = off + raw
        if nxt != pend and data[pend:nxt].count(0) != nxt - pend:
            raise fail(PdoError.RESERVED_BIT, "ALIGN4 padding must be 0 (8.3)", off, nxt, ctrl)
        start = off + head
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
        packets.append(decoded_packet(ctrl & 7, frame, tsfs[tsf], stamp, shape == 4, offset_ns, tag,
                         word >> (29 if ide else 11), d64, ctrl, wire))
        off = nxt
    if len(packets) != count:
        raise fail(PdoError.BAD_HEADER, f"frame_count {count} but {len(packets)} packets in payload_len (6)", off)
    header = StreamHeader(HeaderFlags(flags & 0x3F), seq, seq_end, payload_len, crc, layout_id, mask, count,
                          overflow, crc_alg, (s0, s1, s2, s3), ver_ihl)
    return DecodedStream(header, tuple(packets))
