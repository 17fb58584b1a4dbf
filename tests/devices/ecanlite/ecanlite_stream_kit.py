"""Helpers of the ECAN-Lite frame-stream tests: an independent CRC, a hand-written image builder
(written from the manual's tables, not from the codec) and hypothesis strategies."""

from __future__ import annotations

import struct
from importlib.machinery import ExtensionFileLoader

from hypothesis import strategies as st

from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    Direction,
    StreamEncodeError,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
)
from gatewaylab.devices.ecanlite.stream import packets as packets_module

#: The packet module runs compiled (mypyc): it checks the declared types of its arguments itself, so
#: an argument of a type mypy rejects (a float for an int, an int for an enum) is a TypeError at the
#: call; pure Python refuses it with the LastPDOError a receiver would report.
PACKETS_COMPILED = isinstance(packets_module.__spec__.loader, ExtensionFileLoader)
#: What a packet built from mistyped arguments raises (see PACKETS_COMPILED).
MISTYPED: tuple[type[Exception], ...] = (StreamEncodeError, TypeError) if PACKETS_COMPILED else (StreamEncodeError,)

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def crc16_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit from the parameters of 5.4.4.1 (poly 0x1021, init 0xFFFF,
    no reflection, xorout 0): the reference the codec's crc_hqx is checked against."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def layout_id_by_hand(n: int, mask: int, profile: int, budget: int, options: int) -> int:
    """layout_id exactly as the 5.4.4.1 pseudo-code writes it."""
    layout_word = (((n - 1) & 0x1F) | ((mask & 0xFF) << 5) | ((profile & 0x3F) << 13) | ((budget & 0x03) << 19)
                   | ((options & 0xFF) << 21))
    return (layout_word ^ (layout_word >> 16)) & 0xFFFF


def ctrl_word(ch: int = 0, dlc: int = 0, ide: int = 0, fdf: int = 0, brs: int = 0, x: int = 0, tsf: int = 0,
              kind: int = 0, d64: int = 0) -> int:
    """The 5.4.4.1 control-word formula (plus D64 = bit 15 of chapter 8)."""
    return (ch | (dlc << 3) | (ide << 7) | (fdf << 8) | (brs << 9) | (x << 10) | (tsf << 11) | (kind << 13)
            | (d64 << 15))


def image_by_hand(layout: StreamLayout, seq: int, payload: bytes, frame_count: int, *, flags: int = 0,
                  overflow_sat: int = 0, status: tuple[int, int, int, int] = (0, 0, 0, 0),
                  crc: int | None = None, crc_alg: int = 1, layout_id: int | None = None,
                  channel_mask: int | None = None, seq_end: int | None = None, ver_ihl: int = 0x16,
                  payload_len: int | None = None, tail: bytes = b"") -> bytes:
    """A full image from the chapter 6 offset table: header fields as given (payload_crc16 over
    the first payload_len payload bytes unless ``crc``), payload at 24, ``tail`` after it, zeros
    to 128*N."""
    length = len(payload) if payload_len is None else payload_len
    header = struct.pack(
        "<BBHHHHHBBBB4H", ver_ihl, flags, seq, seq if seq_end is None else seq_end, length,
        crc16_bitwise(payload[:length]) if crc is None else crc,
        layout.layout_id if layout_id is None else layout_id,
        layout.channel_mask if channel_mask is None else channel_mask, frame_count, overflow_sat, crc_alg, *status)
    body = header + payload + tail
    assert len(body) <= layout.pdo_bytes
    return body + bytes(layout.pdo_bytes - len(body))


def std_packet(ch: int, can_id: int, data: bytes, *, dlc: int | None = None, fdf: int = 0, brs: int = 0,
               x: int = 0, tsf: int = 0, ts: bytes = b"", d64: int = 0, id_field: int | None = None,
               pad: int = 0) -> bytes:
    """A standard-id CAN_FRAME laid out by 8.1: Ctrl, StdIdField, Timestamp, Data, padding."""
    dlc = FD_LENGTHS.index(len(data)) if dlc is None else dlc
    ctrl = ctrl_word(ch, dlc, 0, fdf, brs, x, tsf, 0, d64)
    field = can_id if id_field is None else id_field
    return struct.pack("<HH", ctrl, field) + ts + data + bytes(pad)


def ext_packet(ch: int, can_id: int, data: bytes, *, dlc: int | None = None, fdf: int = 0, brs: int = 0,
               x: int = 0, tsf: int = 0, ts: bytes = b"", d64: int = 0, id_aux: int = 0, pad: int = 0) -> bytes:
    """An extended-id CAN_FRAME laid out by 8.1: Ctrl, ExtIdField (ID_AUX in bits 29..31), ..."""
    dlc = FD_LENGTHS.index(len(data)) if dlc is None else dlc
    ctrl = ctrl_word(ch, dlc, 1, fdf, brs, x, tsf, 0, d64)
    return struct.pack("<HI", ctrl, can_id | (id_aux << 29)) + ts + data + bytes(pad)


def tx_result_bytes(ch: int, ref_seq: int, ref_index: int, result: int, pad: int = 0) -> bytes:
    """TX_RESULT of chapter 10: Ctrl (KIND 1) + RefPacketSeq + RefFrameIndex + ResultCode."""
    return struct.pack("<HHBB", ctrl_word(ch, kind=1), ref_seq, ref_index, result) + bytes(pad)


# --------------------------------------------------------------------------------------------- hypothesis

def layouts(direction: Direction | None = None) -> st.SearchStrategy[StreamLayout]:
    """Every legal layout: N 1..24, masks, profiles 0/1/4/5, policies 0-2, options 0..0x1F, both
    directions; features with delta32 too, so every TSF can appear."""
    return st.builds(
        StreamLayout,
        multiplier=st.integers(1, 24),
        channel_mask=st.integers(1, 15),
        profile=st.sampled_from((0, 1, 4, 5)),
        budget_policy=st.integers(0, 2),
        options=st.integers(0, 0x1F),
        direction=st.just(direction) if direction is not None else st.sampled_from(list(Direction)),
        features=st.sampled_from((0x1F3B, 0x1F3F)))


@st.composite
def can_packets(draw: st.DrawFn, layout: StreamLayout) -> CanPacket:
    """A CAN_FRAME ``layout`` can carry: any channel of its mask, classic / remote / FD, both id
    sizes, every TSF and D64 the profile allows."""
    ch = draw(st.sampled_from(layout.channels))
    extended = draw(st.booleans())
    can_id = draw(st.integers(0, 0x1FFFFFFF if extended else 0x7FF))
    id_aux = draw(st.integers(0, 7))
    tsfs = [t for t in Tsf if layout.allows_tsf(t)]
    tsf = draw(st.sampled_from(tsfs))
    scheduled = tsf is Tsf.FULL64 and layout.direction is Direction.RX
    timestamp = 0 if scheduled or tsf is Tsf.NONE else draw(st.integers(0, (1 << (8 * (2, 4, 8)[tsf - 1])) - 1))
    offset_ns = draw(st.integers(0, 0xFFFFFFFF)) if scheduled else 0
    tag = draw(st.integers(0, 0xFFFF)) if scheduled else 0
    d64_ok = layout.profile in (4, 5)
    shape = draw(st.sampled_from(("classic", "remote", "fd")))
    if shape == "classic":
        data = draw(st.binary(max_size=8))
        return CanPacket.of(ch, can_id, extended, data=data, tsf=tsf, timestamp=timestamp, scheduled=scheduled,
                         offset_ns=offset_ns, tag=tag, id_aux=id_aux)
    if shape == "remote":
        return CanPacket.of(ch, can_id, extended, rtr=True, dlc=draw(st.integers(0, 8)), tsf=tsf, timestamp=timestamp,
                         scheduled=scheduled, offset_ns=offset_ns, tag=tag, id_aux=id_aux)
    n = draw(st.sampled_from(FD_LENGTHS))
    return CanPacket.of(ch, can_id, extended, fd=True, brs=draw(st.booleans()), esi=draw(st.booleans()),
                     data=draw(st.binary(min_size=n, max_size=n)), tsf=tsf, timestamp=timestamp,
                     scheduled=scheduled, offset_ns=offset_ns, tag=tag, id_aux=id_aux,
                     d64=d64_ok and draw(st.booleans()))


@st.composite
def tx_results(draw: st.DrawFn, layout: StreamLayout) -> TxResultPacket:
    """A TX_RESULT on a channel of ``layout``."""
    return TxResultPacket(draw(st.sampled_from(layout.channels)), draw(st.integers(0, 0xFFFF)),
                          draw(st.integers(0, 0xFF)), draw(st.sampled_from(list(TxResultCode))))
