"""esd CAN-EtherCAT CoE startup writes -> ECAN-Lite CoE startup writes (``gatewaylab migrate config``).

The esd side is read through the device's own decoders (``esd_can_ethercat.bitrate``: Table 6 for
0xF800:02, Table 9 / UBR / UBRN / LOM for 0xF800:05), the ECAN-Lite side is checked with its bit
timing solver (``ecanlite.bittiming``). Everything not translated one-to-one becomes a
:class:`Note` with the reason and the closest setting: nothing is dropped silently.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.ecanlite import bittiming, image
from gatewaylab.devices.ecanlite.stream import HEADER_SIZE, MAX_FRAME_COUNT
from gatewaylab.devices.esd_can_ethercat import bitrate as esd_rate
from gatewaylab.devices.esd_can_ethercat import objects as esd_obj
from gatewaylab.migrate.eni import InitCmd

__all__ = ["DEFAULT_FALLBACK_RATE", "EsdSettings", "Note", "Translation", "decode_area", "read_esd", "translate"]


#: Packet sizes in the ECAN-Lite frame stream (chapter 8 / 10, profile 0, no ALIGN4): a classic
#: 8-byte frame with a standard identifier 4 + 8, with an extended one 6 + 8; TX_RESULT 6.
STD_PACKET, EXT_PACKET, TX_RESULT_PACKET = 12, 14, 6
STD_LIST_MAX, EXT_LIST_MAX = 64, 24           # 0x800x:41 / :42
FIFO0, RANGE, REJECT_NON_MATCH = 1, 0, 2      # filter action, filter type, :36/:37 value
DEFAULT_FALLBACK_RATE = 500_000               # 0x800x:19 default (13.4)
_SP_WINDOW = (750, 875)                       # 0x800x:21/22 defaults (13.4)


@dataclass(frozen=True, slots=True)
class Note:
    """One thing not translated one-to-one: what, why, and the closest setting written."""

    topic: str
    reason: str
    closest: str


@dataclass(frozen=True, slots=True)
class EsdSettings:
    """The esd configuration the startup writes leave (defaults of 5.1.5.5 / 5.1.5.9 otherwise)."""

    baud_index: int = esd_rate.INDEX_USE_API
    api_baud: int = esd_rate.NTCAN_NO_BAUDRATE
    flags: int = 0
    rx_queue: int = esd_obj.DEFAULT_QUEUE
    tx_queue: int = esd_obj.DEFAULT_QUEUE
    local_rx: int = esd_obj.DEFAULT_LOCAL_QUEUE
    local_tx: int = esd_obj.DEFAULT_LOCAL_QUEUE
    areas: tuple[int, ...] = ()              # 0x8001 identifier areas (UINT64 each)
    status_pdo: bool = False                 # 0x1A85 assigned in 0x1C13
    ignored: tuple[InitCmd, ...] = ()

    @property
    def extended(self) -> bool:
        """29-bit identifiers (0x8000 flags): the packet size, and so the capacity, depends on it."""
        return bool(self.flags & esd_obj.FLAG_29BIT)


@dataclass
class Translation:
    """The ECAN-Lite startup writes, the notes and the capacity arithmetic."""

    cmds: list[InitCmd] = field(default_factory=list)
    notes: list[Note] = field(default_factory=list)
    arithmetic: list[str] = field(default_factory=list)
    multiplier: int = 0
    channel: int = 0
    bitrate: int = 0
    sample_point: int = 0
    listen_only: bool = False


def _u(index: int, sub: int, value: int, size: int, comment: str = "") -> InitCmd:
    return InitCmd(index, sub, value.to_bytes(size, "little"), comment=comment)


def read_esd(cmds: list[InitCmd] | tuple[InitCmd, ...]) -> EsdSettings:
    """Fold the esd startup writes into the settings they leave (later writes win)."""
    s: dict[str, int] = {}
    areas: dict[int, int] = {}
    count: int | None = None
    assign13: dict[int, int] = {}
    ignored: list[InitCmd] = []
    for c in cmds:
        key = (c.index, c.subindex)
        if c.index == 0xF800 and not c.complete_access and c.subindex in (esd_obj.BAUD_INDEX, esd_obj.API_BAUD):
            s["baud_index" if c.subindex == esd_obj.BAUD_INDEX else "api_baud"] = c.value
        elif c.index == 0x8000 and not c.complete_access and c.subindex in (0x20, 0x21, 0x22, 0x23, 0x24):
            s[{0x20: "flags", 0x21: "rx_queue", 0x22: "tx_queue", 0x23: "local_rx", 0x24: "local_tx"}[c.subindex]] = \
                c.value
        elif c.index == 0x8001 and c.complete_access:
            n = c.data[0]
            words = c.data[2:] if c.subindex == 0 else c.data
            first = 1 if c.subindex == 0 else c.subindex
            for i in range(len(words) // 8):
                areas[first + i] = struct.unpack_from("<Q", words, 8 * i)[0]
            count = n if c.subindex == 0 else count
        elif c.index == 0x8001:
            if c.subindex == 0:
                count = c.value
            else:
                areas[c.subindex] = c.value
        elif c.index == 0x1C13:
            if c.complete_access:
                n = c.data[0]
                for i in range(n):
                    assign13[i + 1] = struct.unpack_from("<H", c.data, 2 + 2 * i)[0]
                assign13 = {k: v for k, v in assign13.items() if k <= n}
            elif c.subindex == 0:
                assign13 = {k: v for k, v in assign13.items() if k <= c.value}
            else:
                assign13[c.subindex] = c.value
        elif key[0] == 0x1C12:
            continue                            # 0x1600 is the only RxPDO: nothing to carry over
        else:
            ignored.append(c)
    n_areas = count if count is not None else 0
    return EsdSettings(
        baud_index=s.get("baud_index", esd_rate.INDEX_USE_API),
        api_baud=s.get("api_baud", esd_rate.NTCAN_NO_BAUDRATE),
        flags=s.get("flags", 0),
        rx_queue=s.get("rx_queue", esd_obj.DEFAULT_QUEUE),
        tx_queue=s.get("tx_queue", esd_obj.DEFAULT_QUEUE),
        local_rx=s.get("local_rx", esd_obj.DEFAULT_LOCAL_QUEUE),
        local_tx=s.get("local_tx", esd_obj.DEFAULT_LOCAL_QUEUE),
        areas=tuple(areas.get(i, 0) for i in range(1, n_areas + 1)),
        status_pdo=0x1A85 in assign13.values(), ignored=tuple(ignored))


def decode_area(value: int) -> tuple[bool, int, int]:
    """0x8001 identifier area (5.1.5.6): (29-bit, first, last); bits 31 / 63 mark a 29-bit area."""
    lo, hi = value & 0xFFFFFFFF, value >> 32
    ext = bool(lo & 0x80000000)
    return ext, lo & 0x1FFFFFFF, hi & 0x1FFFFFFF


def _merge(areas: list[tuple[int, int]], limit: int) -> tuple[list[tuple[int, int]], list[str]]:
    """Merge the two neighbours with the smallest gap until ``limit`` ranges remain; the widened list."""
    rs = sorted(areas)
    merged: list[tuple[int, int]] = []
    for a, b in rs:                              # overlapping / touching areas first (no widening)
        if merged and a <= merged[-1][1] + 1:
            merged[-1] = (merged[-1][0], max(b, merged[-1][1]))
        else:
            merged.append((a, b))
    widened: list[str] = []
    while len(merged) > limit:
        i = min(range(len(merged) - 1), key=lambda j: merged[j + 1][0] - merged[j][1])
        gap = (merged[i][1] + 1, merged[i + 1][0] - 1)
        widened.append(f"0x{gap[0]:X}..0x{gap[1]:X}")
        merged[i:i + 2] = [(merged[i][0], merged[i + 1][1])]
    return merged, widened


def _timing(setting: esd_rate.BitRateSetting) -> tuple[int, int, bittiming.BitTiming | None]:
    """(bit rate, sample point in 0.1 %, manual timing or None for the automatic solver)."""
    t = setting.timing
    assert t is not None
    sp = round(t.sample_point * 10)
    try:
        bittiming.solve(setting.requested, sp, sp)
        return setting.requested, sp, None
    except bittiming.BitTimingError:
        pass
    # The 120 MHz esd bit is prescaler * quanta clocks: the same bit on the 80 MHz MCAN clock.
    clocks = t.prescaler * t.time_quanta * bittiming.MCAN_CLOCK_HZ / esd_rate.CONTROLLER_CLOCK
    total = round(clocks)
    if abs(clocks - total) > 1e-9:
        raise bittiming.BitTimingError(f"{setting.requested} bit/s has no whole number of 80 MHz clocks")
    best: tuple[int, bittiming.BitTiming] | None = None
    for brp in range(1, bittiming.NOMINAL.brp[1] + 1):
        if total % brp:
            continue
        tq = total // brp
        if not 5 <= tq <= 1 + 256 + 128:
            continue
        before = round(tq * t.before_sample / t.time_quanta)
        tseg2 = tq - before
        tseg1 = before - 1
        if not (2 <= tseg1 <= 256 and 2 <= tseg2 <= 128):
            continue
        timing = bittiming.BitTiming(brp, tseg1, tseg2, min(tseg2, 128))
        err = abs(timing.sample_point - sp)
        if best is None or err < best[0]:
            best = (err, timing)
    if best is None:
        raise bittiming.BitTimingError(f"no MCAN timing for {setting.requested} bit/s")
    return setting.requested, best[1].sample_point, best[1]


def _bitrate(esd: EsdSettings, tr: Translation, base: int, fallback: int) -> bool:
    """0xF800 -> 0x800x bit timing / node mode; False when the channel stays off (no baud rate)."""
    w = tr.cmds
    if esd.baud_index != esd_rate.INDEX_USE_API:
        setting = esd_rate.from_index(esd.baud_index)
        assert setting is not None
        source = f"0xF800:02 = {esd.baud_index} (Table 6)"
        if esd.api_baud != esd_rate.NTCAN_NO_BAUDRATE:
            tr.notes.append(Note("0xF800:05", f"0x{esd.api_baud:08X} is ignored by the esd: a Table 6 index in "
                                 ":02 wins (5.1.5.9)", f"the :02 rate {setting.requested} bit/s"))
    else:
        setting = esd_rate.from_api(esd.api_baud)
        source = f"0xF800:05 = 0x{esd.api_baud:08X} ({setting.mode.value}" + \
            (", Table 9" if setting.mode is esd_rate.Mode.TABLE else "") + ")"
    if setting.mode is esd_rate.Mode.NONE:
        tr.notes.append(Note("0xF800 no baud rate", "the esd stays off the bus (NTCAN_NO_BAUDRATE); an ECAN-Lite "
                             "channel always has a bit rate", "the channel is left out of 0x8010/0x8011:04 "
                             "(no frames either way) and its 0x800x settings are not written"))
        return False
    if setting.mode is esd_rate.Mode.AUTOBAUD:
        tr.notes.append(Note("0xF800 autobaud", "the ECAN-Lite has no automatic bit rate detection (13.4)",
                             f"listen-only (0x800x:08 = 3) at {fallback} bit/s (--bitrate); set the bus's real rate "
                             "and node mode 0 once known"))
        rate, sp, manual = fallback, 0, None
        tr.listen_only = True
    else:
        rate, sp, manual = _timing(setting)
        tr.listen_only = setting.listen_only
    tr.bitrate, tr.sample_point = rate, sp
    w.append(_u(base, 15, 0, 1, f"classic CAN (from {source})"))
    w.append(_u(base, 16, 0, 1, "no TDC (classic CAN)"))
    if manual is not None:
        w.append(_u(base, 7, 1, 1, "manual bit timing: the 80 MHz clock has no exact automatic solution"))
        w.append(_u(base, 19, rate, 4, "nominal bit rate"))
        for sub, value, size in ((25, manual.brp, 2), (26, manual.tseg1, 1), (27, manual.tseg2, 1),
                                 (28, manual.sjw, 1)):
            w.append(_u(base, sub, value, size))
        tr.sample_point = manual.sample_point
        tr.notes.append(Note("bit timing", f"{rate} bit/s is not a whole number of bit/s on the 80 MHz MCAN clock, "
                             "the automatic solver refuses it (13.4)",
                             f"manual timing BRP {manual.brp} TSEG1 {manual.tseg1} TSEG2 {manual.tseg2}: the esd's "
                             f"bit length, sample point {manual.sample_point / 10:g} %"))
    else:
        w.append(_u(base, 7, 0, 1, "automatic bit timing"))
        w.append(_u(base, 19, rate, 4, "nominal bit rate"))
        lo, hi = (sp, sp) if sp else _SP_WINDOW
        w.append(_u(base, 21, lo, 2, "nominal sample point min (the esd's, 0.1 %)" if sp else "default window"))
        w.append(_u(base, 22, hi, 2, "nominal sample point max"))
    w.append(_u(base, 8, 3 if tr.listen_only else 0, 1, "listen-only (LOM)" if tr.listen_only else "normal mode"))
    return True


def _filters(esd: EsdSettings, tr: Translation, base: int) -> None:
    """0x8001 identifier areas -> standard / extended range filters; non-match rules."""
    w = tr.cmds
    std: list[tuple[int, int]] = []
    ext: list[tuple[int, int]] = []
    for value in esd.areas:
        is_ext, first, last = decode_area(value)
        (ext if is_ext else std).append((first, last))
    if not esd.areas:
        w.append(_u(base, 36, 0, 1, "no esd filter: accept every standard frame"))
        w.append(_u(base, 37, 0 if esd.extended else REJECT_NON_MATCH, 1,
                    "accept every extended frame" if esd.extended else "11-bit mode: reject extended frames"))
    for lst, limit, extended in ((std, STD_LIST_MAX, False), (ext, EXT_LIST_MAX, True)):
        if not lst:
            continue
        merged, widened = _merge(lst, limit)
        if widened:
            tr.notes.append(Note(f"0x8001 {'29' if extended else '11'}-bit areas",
                                 f"{len(lst)} areas, the ECAN-Lite {'extended' if extended else 'standard'} "
                                 f"filter list holds {limit} (0x800x:{42 if extended else 41})",
                                 f"neighbouring areas merged: also passes {', '.join(widened)}"))
        idx_sub, cmd_sub, first_sub = (44, 46, 56) if extended else (43, 45, 50)
        for i, (a, b) in enumerate(merged):
            w.append(_u(base, idx_sub, i, 1, f"{'ext' if extended else 'std'} filter {i}: 0x{a:X}..0x{b:X}"))
            w.append(_u(base, first_sub, RANGE, 1, "range"))
            w.append(_u(base, first_sub + 1, FIFO0, 1, "to RX FIFO0"))
            w.append(_u(base, first_sub + 3, a, 4))
            w.append(_u(base, first_sub + 4, b, 4))
            w.append(_u(base, cmd_sub, 2, 1, "write entry"))
        w.append(_u(base, 55 if extended else 49, len(merged), 1, "filter count"))
    if esd.areas:
        w.append(_u(base, 36, REJECT_NON_MATCH, 1, "reject standard frames outside the areas"))
        w.append(_u(base, 37, REJECT_NON_MATCH, 1, "reject extended frames outside the areas"))
    if not esd.extended and ext:
        tr.notes.append(Note("29-bit areas in 11-bit mode", "the esd's 11-bit queues cannot carry extended "
                             "frames (only counted, 0x2010:3A); the ECAN-Lite delivers them",
                             "the extended filters are written as given"))
    if not esd.extended and not esd.areas:
        tr.notes.append(Note("11-bit mode", "the esd's 11-bit queues drop extended frames (0x2010:3A/3B)",
                             "0x800x:37 = 2 rejects extended frames"))


def _assign(index: int, first: int, n: int, complete: bool) -> list[InitCmd]:
    if complete:
        data = bytes((n, 0)) + b"".join(struct.pack("<H", first + i) for i in range(n))
        return [InitCmd(index, 0, data, True, comment=f"0x{first:04X}..0x{first + n - 1:04X} (complete access)")]
    cmds = [_u(index, 0, 0, 1, "clear")]
    cmds += [_u(index, i + 1, first + i, 2) for i in range(n)]
    cmds.append(_u(index, 0, n, 1, f"{n} chunks"))
    return cmds


def _capacity(esd: EsdSettings, tr: Translation) -> int:
    """The PDO multiplier N carrying at least the esd's frames per cycle (chapter 12 arithmetic)."""
    packet = EXT_PACKET if esd.extended else STD_PACKET
    kind = "29-bit" if esd.extended else "11-bit"
    t, r = esd.tx_queue, esd.rx_queue
    out_need = t * packet
    in_need = r * packet + t * TX_RESULT_PACKET
    a = tr.arithmetic
    a.append(f"esd per cycle: {t} Tx + {r} Rx messages ({kind}); ECAN-Lite packets {packet} B per frame, "
             f"{TX_RESULT_PACKET} B per TX_RESULT, frame area = 128 x N - {HEADER_SIZE}")
    a.append(f"outputs (0x8011): {t} x {packet} = {out_need} B -> N >= ceil(({out_need} + {HEADER_SIZE}) / 128) = "
             f"{math.ceil((out_need + HEADER_SIZE) / 128)}")
    a.append(f"inputs (0x8010): {r} x {packet} + {t} x {TX_RESULT_PACKET} (TX_RESULT for the transaction numbers) = "
             f"{in_need} B -> N >= ceil(({in_need} + {HEADER_SIZE}) / 128) = "
             f"{math.ceil((in_need + HEADER_SIZE) / 128)}")
    n = max(1, math.ceil((max(out_need, in_need) + HEADER_SIZE) / 128))
    if n > image.CHUNKS:
        tr.notes.append(Note("queue sizes", f"{t} + {r} frames per cycle need N = {n}, the ECAN-Lite allows "
                             f"{image.CHUNKS} (13.2)", f"N = {image.CHUNKS}: "
                             f"{(128 * image.CHUNKS - HEADER_SIZE) // packet} frames per cycle each way at most"))
        n = image.CHUNKS
    area = 128 * n - HEADER_SIZE
    a.append(f"N = {n}: {128 * n} B per direction, frame area {area} B = {area // packet} frames of {packet} B "
             f"(esd: {t} out / {r} in), at most {MAX_FRAME_COUNT} packets per image")
    if r + t > MAX_FRAME_COUNT:
        tr.notes.append(Note("packets per image", f"{r} frames + {t} TX_RESULTs exceed {MAX_FRAME_COUNT} packets",
                             "the rest follows in the next cycle"))
    return n


def translate(cmds: list[InitCmd] | tuple[InitCmd, ...], channel: int = 0, complete_access: bool = False,
              fallback_rate: int = DEFAULT_FALLBACK_RATE) -> Translation:
    """The ECAN-Lite startup writes (manual 5.4.2 order) for the esd startup writes ``cmds``."""
    if not 0 <= channel <= 3:
        raise ConfigError(f"channel {channel} is not 0..3")
    esd = read_esd(cmds)
    tr = Translation(channel=channel)
    n = _capacity(esd, tr)
    tr.multiplier = n
    tr.cmds += _assign(0x1C12, image.RX_MAP, n, complete_access)
    tr.cmds += _assign(0x1C13, image.TX_MAP, n, complete_access)
    base = 0x8001 + channel
    body: list[InitCmd] = []
    keep, tr.cmds = tr.cmds, body
    on_bus = _bitrate(esd, tr, base, fallback_rate)
    if on_bus:
        _filters(esd, tr, base)
        body.append(_u(base, 1, 1, 1, f"apply MCAN{channel}"))
    else:
        body.clear()
    tr.cmds = keep
    mask = (1 << channel) if on_bus else 0
    if not on_bus:
        tr.notes.append(Note("channel mask", "a mask of 0 carries no frames", "0x8010/0x8011:04 = 0"))
    for index, opts, what in ((image.TX_PROFILE, 1, "TxPDO"), (image.RX_PROFILE, 0, "RxPDO")):
        tr.cmds += [_u(index, 3, n, 1, f"{what} N = {n} ({128 * n} B)"),
                    _u(index, 4, mask, 1, f"channel mask: MCAN{channel} only"),
                    _u(index, 5, 0, 1, "profile 0: classic inline, no timestamp"),
                    _u(index, 6, 0, 1, "budget Balanced (one channel: the whole frame area)"),
                    _u(index, 7, opts, 1, "TX_RESULT on (esd transaction numbers)" if opts else "no options")]
    tr.cmds += [_u(image.TX_PROFILE, 1, 1, 1, "apply TxPDO profile"),
                _u(image.RX_PROFILE, 1, 1, 1, "apply RxPDO profile")]
    tr.cmds += body
    tr.notes.append(Note("esd local queues", f"0x8000:23/24 = {esd.local_rx} / {esd.local_tx} frames: the "
                         "ECAN-Lite has no configurable local queue depth",
                         "the MCAN RX FIFO0 / TX FIFO (0x800x:62 / :70, defaults 48 / 32) and the device's RX "
                         "cache; frames beyond are counted in 0x9020.., 0x8010:16"))
    if esd.status_pdo:
        tr.notes.append(Note("0x1A85 status PDO", "the ECAN-Lite has no separate status PDO",
                             f"the channel status word of MCAN{channel} in every TxPDO header (chapter 7); "
                             f"TEC/REC in 0x{0x9000 + channel:04X}:01 (ECR), bus-off / warning in :02 (PSR)"))
    for c in esd.ignored:
        tr.notes.append(Note(f"0x{c.index:04X}:{c.subindex:02X}", "no ECAN-Lite counterpart is known to the translator",
                             "not written"))
    return tr
