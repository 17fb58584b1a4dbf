"""ECAN-Lite frame stream: pack + parse of a full 3072-byte image per second.

The image is N = 24 (3048-byte frame area), all four channels, classic 8-byte and CAN FD frames
mixed (standard and extended ids, FD lengths 12..64), filled until the next packet no longer fits.
Measured in one run:

- the codec: ``encode_into`` (validation, packets, zeroing, CRC, header) + ``decode_stream``
  (header checks, CRC, every packet checked and built as a frozen ``CanPacket``);
- the baseline: a plain ``struct`` loop written here that packs the same packets and unpacks them
  into tuples, with the same CRC and zeroing but no validation and no objects.

Rounds alternate between all measured functions; the fastest round of each counts (the machine
is shared) and the median round is printed beside it. Targets: <= 50 us per image
pack + parse compiled, pure Python <= 1.5x the struct loop; both run side by side in one run, each
in its own child process (benchmarks/sides.py: GATEWAYLAB_PURE=1 and the default build). Printed,
never asserted, together with the floors that explain the pure-Python time: the CRC-16 of the frame
area, building the packets alone (19 slot stores per packet, as plain objects and as the frozen
``CanFrame`` + ``CanPacket`` records the decoder builds), and the baseline's bare unpack loop.
"""

from __future__ import annotations

import binascii
import statistics
import struct
import time
from collections.abc import Callable

from benchmarks.sides import both, compare, quick
from benchmarks.targets import record
from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    StreamLayout,
    crc16,
    decode_stream,
    encode_into,
    packet_size,
)

#: Calls of each measured function per round, and rounds.
PER_ROUND = 100
ROUNDS = 25
_HDR = struct.Struct("<BBHHHHHBBBB4H")
_STD = struct.Struct("<HH")
_EXT = struct.Struct("<HI")
_FD_LENS = (12, 16, 20, 24, 32, 48, 64)
#: the side-by-side table: label, measure()'s key, format
SIDE_ROWS = (("codec pack+parse, us/image", "codec_us", ".1f"),
             ("plain struct loop (baseline), us/image", "baseline_us", ".1f"),
             ("ratio codec / baseline", "ratio", ".2f"),
             ("pure-Python floor (2 CRC + objects), us", "floor_us", ".0f"),
             ("frozen records alone (CanFrame + CanPacket), us", "records_us", ".0f"))


def mixed_packets(layout: StreamLayout) -> list[CanPacket]:
    """Classic and FD frames on the four channels in turn until the frame area is full."""
    out: list[CanPacket] = []
    used = 0
    i = 0
    while True:
        ch = i % 4
        if i % 2:
            n = _FD_LENS[i // 2 % len(_FD_LENS)]
            p = CanPacket.of(ch, 0x100 + i, extended=bool(i % 3 == 0), fd=True, brs=bool(i % 4 == 1),
                          data=bytes((i + k) & 0xFF for k in range(n)))
            if i % 3 == 0:
                p = CanPacket.of(ch, 0x18FF0000 + i, extended=True, fd=True, data=p.data)
        else:
            p = CanPacket.of(ch, 0x200 + i, data=bytes((i * 7 + k) & 0xFF for k in range(8)))
        size = packet_size(p, layout)
        if used + size > layout.frame_area_bytes or len(out) == 255:
            return out
        out.append(p)
        used += size
        i += 1


def baseline_roundtrip(buf: bytearray, rows: list[tuple[int, int, bool, bytes]],
                       seq: int) -> list[tuple[int, int, bytes]]:
    """Plain struct: pack the pre-computed (ctrl, id, ext, data) rows, CRC, header; unpack again."""
    off = 24
    for ctrl, ident, ext, data in rows:
        if ext:
            _EXT.pack_into(buf, off, ctrl, ident)
            off += 6
        else:
            _STD.pack_into(buf, off, ctrl, ident)
            off += 4
        n = len(data)
        buf[off:off + n] = data
        off += n
    end = len(buf)
    buf[off:end] = bytes(end - off)
    crc = binascii.crc_hqx(memoryview(buf)[24:off], 0xFFFF)
    _HDR.pack_into(buf, 0, 0x16, 0, seq, seq, off - 24, crc, 0, 0x0F, len(rows), 0, 1, 0, 0, 0, 0)
    # parse
    out = []
    hdr = _HDR.unpack_from(buf, 0)
    stop = 24 + hdr[4]
    if binascii.crc_hqx(memoryview(buf)[24:stop], 0xFFFF) != hdr[5]:
        raise ValueError("crc")
    off = 24
    lens = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
    while off < stop:
        ctrl = _STD.unpack_from(buf, off)[0]
        if ctrl & 0x80:
            ident = _EXT.unpack_from(buf, off)[1]
            off += 6
        else:
            ident = _STD.unpack_from(buf, off)[1]
            off += 4
        n = lens[ctrl >> 3 & 15]
        out.append((ctrl, ident, bytes(buf[off:off + n])))
        off += n
    return out


def bare_parse(buf: bytearray) -> list[tuple[int, int, bytes]]:
    """The baseline's parse half on its own (no CRC): the cost of just reading the packets."""
    out = []
    stop = 24 + _HDR.unpack_from(buf, 0)[4]
    off = 24
    lens = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
    while off < stop:
        ctrl = _STD.unpack_from(buf, off)[0]
        if ctrl & 0x80:
            ident = _EXT.unpack_from(buf, off)[1]
            off += 6
        else:
            ident = _STD.unpack_from(buf, off)[1]
            off += 4
        n = lens[ctrl >> 3 & 15]
        out.append((ctrl, ident, bytes(buf[off:off + n])))
        off += n
    return out


class _Slots:
    """A plain object of 19 slots (what the decoder builds per packet, measured without gatewaylab's
    internals so that the floor survives changes to the packet class)."""

    __slots__ = tuple(f"s{k}" for k in range(19))

    def __init__(self, s0: object, s1: object, s2: object, s3: object, s4: object, s5: object, s6: object,
                 s7: object, s8: object, s9: object, s10: object, s11: object, s12: object, s13: object,
                 s14: object, s15: object, s16: object, s17: object, s18: object) -> None:
        self.s0, self.s1, self.s2, self.s3, self.s4, self.s5, self.s6 = s0, s1, s2, s3, s4, s5, s6
        self.s7, self.s8, self.s9, self.s10, self.s11, self.s12, self.s13 = s7, s8, s9, s10, s11, s12, s13
        self.s14, self.s15, self.s16, self.s17, self.s18 = s14, s15, s16, s17, s18


def build_packets_only(rows: list[tuple[object, ...]]) -> list[_Slots]:
    """What the decoder spends on objects alone: for each packet a new instance with its 19 slots
    stored from values already at hand (``rows``: 19 values per packet)."""
    return [_Slots(*row) for row in rows]


def build_records_only(rows: list[tuple[CanFrame, CanPacket]]) -> list[CanPacket]:
    """What the decoder spends on its frozen records alone: per packet a ``CanFrame`` and a ``CanPacket``
    built the way the decoder builds them, from values already at hand (``rows``: the packets to copy)."""
    return [CanPacket(p.channel, CanFrame(f.can_id, f.data, f.extended, f.rtr, f.fd, f.brs, f.esi,
                                          f.dlc if f.rtr else -1),
                      p.tsf, p.timestamp, p.scheduled, p.offset_ns, p.tag, p.id_aux, p.d64, ctrl=p.ctrl, wire=p.wire)
            for f, p in rows]


def _time_interleaved(fns: dict[str, Callable[[int], object]]) -> dict[str, tuple[float, float]]:
    """(best, median) seconds per call of each function: rounds alternate between them, so a load
    spike on the shared machine does not favour one side."""
    samples: dict[str, list[float]] = {name: [] for name in fns}
    for fn in fns.values():
        for k in range(50):
            fn(k)
    for _ in range(ROUNDS):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            for k in range(PER_ROUND):
                fn(k)
            samples[name].append((time.perf_counter() - t0) / PER_ROUND)
    return {name: (min(v), statistics.median(v)) for name, v in samples.items()}


def _run(layout: StreamLayout, packets: list[CanPacket]) -> dict[str, float]:
    """Measure and print one image; returns the codec's and the baseline's best us per pack + parse and
    the floor nothing can go below in pure Python: two CRC-16 passes plus building the packets."""
    buf = bytearray(layout.pdo_bytes)
    payload = sum(packet_size(p, layout) for p in packets)
    fd = sum(p.fd for p in packets)
    rows = [(p.ctrl, p.can_id, p.extended, p.data) for p in packets]
    record_rows = [(p.frame, p) for p in packets]
    slot_rows: list[tuple[object, ...]] = [(p.channel, p.can_id, p.extended, p.fd, p.brs, p.rtr, p.esi, p.data,
                                            *range(11)) for p in packets]

    def codec(seq: int) -> None:
        encode_into(buf, layout, seq, packets)
        decoded = decode_stream(buf, layout)
        assert len(decoded.packets) == len(packets)

    def baseline(seq: int) -> None:
        assert len(baseline_roundtrip(buf, rows, seq)) == len(rows)

    # the two must put the same bytes in the frame area, and the codec must read back its packets
    encode_into(buf, layout, 1, packets)
    ours = bytes(buf[24:24 + payload])
    assert decode_stream(buf, layout).packets == tuple(packets)
    image = bytearray(buf)
    baseline_roundtrip(buf, rows, 1)
    assert bytes(buf[24:24 + payload]) == ours, "baseline and codec disagree on the frame area"
    area = bytes(image[24:24 + payload])

    t = _time_interleaved({
        "baseline": baseline, "codec": codec,
        "pack": lambda seq: encode_into(buf, layout, seq, packets),
        "parse": lambda seq: decode_stream(image, layout),
        "crc": lambda seq: crc16(area),
        "objects": lambda seq: build_packets_only(slot_rows),
        "records": lambda seq: build_records_only(record_rows),
        "unpack": lambda seq: bare_parse(image)})
    (t_base, m_base), (t_codec, m_codec) = t["baseline"], t["codec"]
    t_enc, t_dec, t_crc, t_obj, t_unp, t_rec = (t[k][0] for k in ("pack", "parse", "crc", "objects", "unpack",
                                                                    "records"))
    us = 1e6
    print(f"image: N={layout.multiplier}, {layout.pdo_bytes} B, {len(packets)} packets ({fd} CAN FD, "
          f"{len(packets) - fd} classic), payload {payload} B, 4 channels; best (median) of {ROUNDS} rounds")
    print(f"  codec    pack+parse: {t_codec * us:8.1f} us/image ({m_codec * us:.1f})  {1 / t_codec:9.0f} images/s  "
          f"(pack {t_enc * us:.1f} us, parse {t_dec * us:.1f} us, {t_codec / len(packets) * us:.2f} us/packet)")
    print(f"  baseline struct loop: {t_base * us:8.1f} us/image ({m_base * us:.1f})  {1 / t_base:9.0f} images/s")
    print(f"  ratio codec/baseline: {t_codec / t_base:.2f}")
    print(f"  floors: CRC-16 of the {payload}-byte frame area {t_crc * us:.1f} us (once in pack, once in parse); "
          f"building {len(packets)} 19-slot objects alone {t_obj * us:.1f} us; bare struct unpack of the same bytes "
          f"into tuples {t_unp * us:.1f} us; the frozen records alone ({len(packets)} CanFrame + CanPacket) "
          f"{t_rec * us:.1f} us")
    print(f"  => parse with objects cannot go below ~{(t_crc + t_obj + t_unp) * us:.0f} us, pack below "
          f"~{t_crc * us:.0f} us (the packet bytes are joined, not packed, in encode_into)")
    return {"codec_us": t_codec * us, "baseline_us": t_base * us, "ratio": t_codec / t_base,
            "floor_us": (2 * t_crc + t_obj) * us, "records_us": t_rec * us}


def measure() -> dict[str, float]:
    """Both images measured and printed; the numbers of the mixed one (the target's)."""
    global ROUNDS
    if quick():
        ROUNDS = 7
    layout = StreamLayout(multiplier=24, channel_mask=0x0F)
    mixed = _run(layout, mixed_packets(layout))
    # For scale: the same area filled with 64-byte CAN FD frames only (fewer, larger packets).
    fd64 = [CanPacket.of(k % 4, 0x300 + k, fd=True, brs=True, data=bytes([k]) * 64)
            for k in range(layout.frame_area_bytes // 68)]
    _run(layout, fd64)
    return mixed


def targets() -> None:
    """Pure and compiled children side by side; records the two codec targets."""
    sides = pure, default = compare("bench_ecanlite_stream", "ECAN-Lite stream, mixed N=24 image (best round)",
                                    SIDE_ROWS)
    d, p = default.result, pure.result
    record("codec", both(sides, "codec_us", ".1f", " us"), d["codec_us"] <= 50)
    record("codec_pure", f"{p['ratio']:.2f}x ({p['codec_us']:.1f} us vs struct loop {p['baseline_us']:.1f} us)",
           p["ratio"] <= 1.5)


def main() -> None:
    targets()
