"""can-utils' text forms of CAN frames, as pure functions: what ``candump`` prints, its filters and
timestamps, and the frame syntax ``cansend`` takes.

Byte for byte what can-utils' lib.c writes (``snprintf_long_canframe``) and candump.c prints
(``sprint_timestamp``, the filter option), so a line of ``gatewaylab dump`` reads like a line of
``candump`` and a filter or a frame typed for can-utils means the same here. Only usage errors
(:class:`CandumpSyntaxError`) come out of the parsers.
"""

from __future__ import annotations

import datetime
import re
from dataclasses import dataclass

from gatewaylab.bus.errorframe import CAN_ERR_FLAG, CAN_ERR_MASK, ErrorFrame
from gatewaylab.bus.frame import FD_DLC_TO_LEN, CanFrame
from gatewaylab.common.errors import FrameError, LocalError

__all__ = [
    "CAN_EFF_FLAG",
    "CAN_EFF_MASK",
    "CAN_INV_FILTER",
    "CAN_RTR_FLAG",
    "CAN_SFF_MASK",
    "TIMESTAMP_MODES",
    "CandumpSyntaxError",
    "FilterSet",
    "IdFilter",
    "IdRow",
    "IdTable",
    "Timestamps",
    "line",
    "long_error_frame",
    "long_frame",
    "parse_cansend",
    "parse_filters",
    "socketcan_id",
]


#: SocketCAN can_id flags (linux/can.h): extended frame, remote frame, inverted filter.
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_INV_FILTER = 0x20000000
CAN_SFF_MASK = 0x7FF
CAN_EFF_MASK = 0x1FFFFFFF
#: The timestamp modes of ``candump -t``: absolute, absolute with date, delta, zero-based.
TIMESTAMP_MODES = ("a", "A", "d", "z")


class CandumpSyntaxError(LocalError, ValueError):
    """A filter or frame written in can-utils syntax that cannot be read (a usage error)."""


def socketcan_id(frame: CanFrame) -> int:
    """The frame's can_id as the kernel hands it out: id plus CAN_EFF_FLAG / CAN_RTR_FLAG."""
    return frame.can_id | (CAN_EFF_FLAG if frame.extended else 0) | (CAN_RTR_FLAG if frame.rtr else 0)


# -- the long (candump) form --------------------------------------------------------------------
def long_frame(frame: CanFrame, indent_sff: bool = False) -> str:
    """``snprintf_long_canframe`` without view options: ``123   [3]  11 22 33``,
    ``12345678  [12]  ...`` (CAN FD), ``123   [0]  remote request``; ``indent_sff`` indents an
    11-bit id by 5 columns (candump does once it saw a 29-bit frame)."""
    ident = f"{frame.can_id:08X}" if frame.extended else (" " * 5 if indent_sff else "") + f"{frame.can_id:03X}"
    if frame.fd:
        head = f"{ident}  [{len(frame.data):02d}]"
    elif frame.rtr:
        return f"{ident}   [{frame.dlc}]  remote request"
    else:
        head = f"{ident}   [{len(frame.data)}]"
    return head + " " + "".join(f" {b:02X}" for b in frame.data)


def long_error_frame(frame: ErrorFrame) -> str:
    """An error frame in the long form: ``20000088   [8]  00 00 ... 00   ERRORFRAME``."""
    data = frame.data[:8]
    ident = f"{(frame.can_id & CAN_ERR_MASK) | CAN_ERR_FLAG:08X}"
    return (f"{ident}   [{len(data)}] " + "".join(f" {b:02X}" for b in data)
            + "ERRORFRAME".rjust(3 * (8 - len(data)) + 13))


def line(body: str, channel: str, stamp: str = "", channel_width: int = 0) -> str:
    """One candump output line: `` (stamp)  can0  <body>`` (``stamp`` from :class:`Timestamps`)."""
    return f" {stamp} {channel.rjust(channel_width)}  {body}"


class Timestamps:
    """``candump -t a|A|d|z``: absolute ``(1700000000.123456) ``, with date, delta to the previous
    frame, or since the first frame (``(000.012345) ``); no mode: empty. Times in seconds."""

    def __init__(self, mode: str | None, tz: datetime.tzinfo | None = None) -> None:
        if mode is not None and mode not in TIMESTAMP_MODES:
            raise CandumpSyntaxError(f"timestamp mode {mode!r}: use a (absolute), A (with date), "
                                     "d (delta) or z (from zero)")
        self.mode = mode
        self.tz = tz
        self._last: int | None = None

    def text(self, t: float) -> str:
        """The stamp of a frame at Unix time ``t`` (trailing space included, as candump)."""
        us = round(t * 1_000_000)
        if self.mode == "a":
            return f"({us // 1_000_000:010d}.{us % 1_000_000:06d}) "
        if self.mode == "A":
            when = datetime.datetime.fromtimestamp(us // 1_000_000, self.tz)
            return f"({when:%Y-%m-%d %H:%M:%S}.{us % 1_000_000:06d}) "
        if self.mode in ("d", "z"):
            if self._last is None:
                self._last = us
            diff = max(0, us - self._last)
            if self.mode == "d":
                self._last = us
            return f"({diff // 1_000_000:03d}.{diff % 1_000_000:06d}) "
        return ""


# -- filters ------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class IdFilter:
    """``<can_id>:<can_mask>`` (or ``~``: inverted) in candump's syntax and the kernel's rule."""

    can_id: int
    can_mask: int
    inverted: bool = False

    def matches(self, sid: int) -> bool:
        """``sid`` is a SocketCAN can_id (:func:`socketcan_id`)."""
        hit = (sid & self.can_mask) == (self.can_id & self.can_mask)
        return hit != self.inverted


@dataclass(frozen=True, slots=True)
class FilterSet:
    """The filters of one ``candump IFACE,filter,...``: any (or with ``j`` every) id filter passes a
    data frame, no id filter passes all (``0:0``); error frames pass by ``#err_mask`` class bits."""

    filters: tuple[IdFilter, ...] = ()
    join: bool = False
    err_mask: int = 0

    def accepts(self, frame: CanFrame) -> bool:
        """True when a data frame passes the candump-style id/mask filters (no filter: all pass)."""
        if not self.filters:
            return True
        sid = socketcan_id(frame)
        if self.join:
            return all(f.matches(sid) for f in self.filters)
        return any(f.matches(sid) for f in self.filters)

    def accepts_error(self, frame: ErrorFrame) -> bool:
        """True when an error frame's class bits are in the error mask."""
        return bool(self.err_mask & frame.can_id & CAN_ERR_MASK)


_FILTER = re.compile(r"([0-9A-Fa-f]{1,8})([:~])([0-9A-Fa-f]{1,8})")
_ERRMASK = re.compile(r"#([0-9A-Fa-f]{1,8})")


def parse_filters(specs: str | list[str] | tuple[str, ...]) -> FilterSet:
    """Comma separated candump filters (``123:7FF``, ``400~7F0``, ``#000000FF``, ``j``); several
    specs (one per ``-f``) add up. An 8-digit id sets CAN_EFF_FLAG, as candump does."""
    items: list[str] = []
    for spec in [specs] if isinstance(specs, str) else specs:
        items += spec.split(",")
    filters: list[IdFilter] = []
    join = False
    err_mask = 0
    for item in items:
        m = _FILTER.fullmatch(item)
        if m is not None:
            can_id, mask = int(m[1], 16), int(m[3], 16) & ~CAN_INV_FILTER
            if len(m[1]) == 8:
                can_id |= CAN_EFF_FLAG
            filters.append(IdFilter(can_id & ~CAN_INV_FILTER, mask, m[2] == "~"))
        elif item in ("j", "J"):
            join = True
        elif (e := _ERRMASK.fullmatch(item)) is not None:
            err_mask = int(e[1], 16)
        else:
            raise CandumpSyntaxError(
                f"filter {item!r}: use <can_id>:<can_mask> (matches when id & mask == can_id & mask), "
                "<can_id>~<can_mask> (when it differs), #<error_mask> or j (join); hex, e.g. 123:7FF")
    return FilterSet(tuple(filters), join, err_mask)


# -- the compact (cansend) form -----------------------------------------------------------------
_HEX = set("0123456789abcdefABCDEF")


def _hex(text: str, what: str, spec: str) -> int:
    if not text or not set(text) <= _HEX:
        raise CandumpSyntaxError(f"frame {spec!r}: {what} {text!r} is not hexadecimal")
    return int(text, 16)


_USAGE = ("<can_id>#{data} (3 hex digits: 11-bit id, 8: 29-bit), <can_id>#R{len} (remote frame), "
          "<can_id>##<flags>{data} (CAN FD, flags 0..F: 1 BRS, 2 ESI); data in hex bytes, optionally "
          "separated by '.', e.g. 123#DEADBEEF")


def parse_cansend(spec: str) -> CanFrame:
    """A frame in ``cansend``'s syntax (can-utils lib.h ``parse_canframe``): ``123#DEADBEEF``,
    ``12345678#11.22``, ``123#R``, ``123#R5``, ``123##1AABB`` (CAN FD, flags nibble: 1 BRS, 2 ESI)."""
    spec = spec.strip()
    ident, sep, rest = spec.partition("#")
    if not sep:
        raise CandumpSyntaxError(f"frame {spec!r}: no '#'; the syntax is {_USAGE}")
    if len(ident) == 3:
        extended = False
    elif len(ident) == 8:
        extended = True
    else:
        raise CandumpSyntaxError(f"frame {spec!r}: the id has {len(ident)} digits; use 3 (11-bit) or 8 (29-bit)")
    can_id = _hex(ident, "id", spec)
    if extended and can_id & CAN_ERR_FLAG:
        raise CandumpSyntaxError(f"frame {spec!r}: id 0x{can_id:08X} has CAN_ERR_FLAG (0x20000000) set: "
                                 "error frames are not sent (inject bus errors with `gatewaylab fault`)")
    if extended and can_id > CAN_EFF_MASK:
        raise CandumpSyntaxError(f"frame {spec!r}: a 29-bit id is at most 1FFFFFFF")
    if not extended and can_id > CAN_SFF_MASK:
        raise CandumpSyntaxError(f"frame {spec!r}: an 11-bit id is at most 7FF (use 8 digits for 29-bit ids)")
    fd = brs = esi = False
    if rest[:1] in ("R", "r"):
        dlc_text = rest[1:]
        if len(dlc_text) > 1 or (dlc_text and dlc_text not in "012345678"):
            raise CandumpSyntaxError(f"frame {spec!r}: a remote frame takes an optional length 0..8 after R")
        try:
            return CanFrame(can_id, b"", extended, rtr=True, dlc=int(dlc_text or "0"))
        except FrameError as exc:
            raise CandumpSyntaxError(f"frame {spec!r}: {exc}") from None
    if rest[:1] == "#":
        if len(rest) < 2:
            raise CandumpSyntaxError(f"frame {spec!r}: CAN FD needs a flags nibble after '##' (0..F)")
        flags = _hex(rest[1], "flags nibble", spec)
        fd, brs, esi = True, bool(flags & 1), bool(flags & 2)
        rest = rest[2:]
    if "_" in rest:
        raise CandumpSyntaxError(f"frame {spec!r}: a raw DLC (_9.._F) is not modelled by the virtual bus")
    data = bytearray()
    i = 0
    while i < len(rest):
        if rest[i] == ".":
            i += 1
            continue
        pair = rest[i:i + 2]
        if len(pair) < 2:
            raise CandumpSyntaxError(f"frame {spec!r}: odd number of hex digits in the data")
        data.append(_hex(pair, "data byte", spec))
        i += 2
    limit = 64 if fd else 8
    if len(data) > limit:
        raise CandumpSyntaxError(f"frame {spec!r}: {len(data)} data bytes, at most {limit} "
                                 f"{'in CAN FD' if fd else 'in classic CAN (use ## for CAN FD)'}")
    if fd:
        # cansend.c: "ensure discrete CAN FD length values": padded with zeros to the next DLC length
        data += bytes(next(n for n in FD_DLC_TO_LEN if n >= len(data)) - len(data))
    try:
        return CanFrame(can_id, bytes(data), extended, fd=fd, brs=brs, esi=esi)
    except FrameError as exc:
        raise CandumpSyntaxError(f"frame {spec!r}: {exc}") from None


# -- the per-id table (python-can's can.viewer) -------------------------------------------------
@dataclass(slots=True)
class IdRow:
    """One identifier of the table: how often it came, its last period and data."""

    frame: CanFrame
    count: int
    first_t: float
    last_t: float
    period: float | None = None

    @property
    def key(self) -> tuple[bool, int]:
        """The row's sort and lookup key: (extended, CAN id)."""
        return self.frame.extended, self.frame.can_id


class IdTable:
    """can.viewer's table: one row per identifier with count, period (time between its last two
    frames) and last data; rows sorted by id, 11-bit before 29-bit."""

    def __init__(self) -> None:
        self.rows: dict[tuple[bool, int], IdRow] = {}

    def feed(self, frame: CanFrame, t: float) -> IdRow:
        """Count a frame into its identifier's row (made on first sight); returns the row."""
        key = (frame.extended, frame.can_id)
        row = self.rows.get(key)
        if row is None:
            row = self.rows[key] = IdRow(frame, 1, t, t)
        else:
            row.period = t - row.last_t
            row.frame, row.count, row.last_t = frame, row.count + 1, t
        return row

    def sorted_rows(self) -> list[IdRow]:
        """The rows by identifier, base frames first."""
        return [self.rows[k] for k in sorted(self.rows)]

    def lines(self, now: float) -> list[str]:
        """The table as text: ``count  period  age  id  [len]  data``."""
        out = [f"{'count':>8}  {'period ms':>9}  {'age s':>7}  {'id':>8}  len  data"]
        for row in self.sorted_rows():
            f = row.frame
            ident = f"{f.can_id:08X}" if f.extended else f"{f.can_id:03X}"
            period = "" if row.period is None else f"{row.period * 1000:.1f}"
            data = "remote request" if f.rtr else f.data.hex(" ").upper()
            out.append(f"{row.count:>8}  {period:>9}  {now - row.last_t:>7.2f}  {ident:>8}  "
                       f"{('[' + str(f.dlc if f.rtr else len(f.data)) + ']'):>4}  {data}")
        return out
