"""Faults of the line between the master and the segment (sans-I/O): lost, corrupted, delayed, duplicated and
reordered frames, offset working counters, a link that is down.

A :class:`LineFaults` sits on a :class:`~gatewaylab.ethercat.segment.Segment` (``segment.line_faults``) while a
fault is armed; a transport that finds it there and :attr:`LineFaults.engaged` hands each frame to
:meth:`LineFaults.serve` instead of ``Segment.process``, sends the frame back when that says so, and sends
what :meth:`LineFaults.due` releases (delayed, duplicated, reordered replies) when their time comes. Time
is a number of seconds the transport passes in (its own monotonic clock); nothing here sleeps or reads a clock.

Where each fault acts (ETG.1000.4 frame processing; docs/faults.md "EtherCAT faults"):

* lose (both ways) and link down: the request never reaches slave 0 -- nothing is processed.
* lose ``replies`` and corrupt: the slaves process the frame (registers, AL state, outputs change) and the
  reply is lost on its way back. A corrupted reply is one whose FCS the master's NIC finds wrong: it
  discards the frame (IEEE 802.3 FCS check), so the master sees a lost frame, as with a lost reply.
* working counter offset: added (modulo 2^16) to the WKC of matching datagrams after the slaves' work.
* delay: the reply leaves ``delay`` (+ uniform jitter from a seeded generator) later; replies keep their
  order (a queue, as in a switch). duplicate: the reply is sent twice. reorder: the reply is held until
  the next reply has gone out (at most :data:`REORDER_HOLD_S`), then sent after it.

A fault counts frames (lose, corrupt, duplicate, reorder) or datagrams (WKC offset) that match its
:class:`Match`; once its count is used up it leaves the line and calls its ``on_end``.
"""

from __future__ import annotations

import enum
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from gatewaylab.ethercat.datagram import (
    DATAGRAM_HEADER,
    ECAT_HEADER,
    ECAT_HEADER_LEN,
    ECAT_TYPE_DATAGRAMS,
    ETH_HEADER,
    ETH_HEADER_LEN,
    ETHERTYPE_ETHERCAT,
    LEN_MASK,
    MORE,
    WKC,
    Command,
)
from gatewaylab.ethercat.errors import EtherCATConfigError

if TYPE_CHECKING:
    from gatewaylab.ethercat.segment import Segment

__all__ = [
    "ANY_DATAGRAM",
    "CONFIGURED_COMMANDS",
    "LOGICAL_COMMANDS",
    "REORDER_HOLD_S",
    "Kind",
    "LineFault",
    "LineFaults",
    "Match",
    "datagrams_of",
    "parse_command",
]

#: The longest a reordered reply waits for the next reply before it goes out alone.
REORDER_HOLD_S: Final = 0.005
#: Commands that address a slave by its configured station address (ADP), ETG.1000.4.
CONFIGURED_COMMANDS: Final = frozenset({Command.FPRD, Command.FPWR, Command.FPRW, Command.FRMW})
#: Commands that address the logical process image (the 32-bit address field), ETG.1000.4.
LOGICAL_COMMANDS: Final = frozenset({Command.LRD, Command.LWR, Command.LRW})


def parse_command(text: str | int) -> int:
    """A datagram command by name (``LRW``, case-insensitive) or number (0..14); EtherCATConfigError otherwise."""
    if isinstance(text, int):
        value = text
    else:
        name = text.strip().upper()
        if name in Command.__members__:
            return int(Command[name])
        try:
            value = int(name, 0)
        except ValueError:
            raise EtherCATConfigError(f"unknown datagram command {text!r} (one of {', '.join(Command.__members__)} "
                             f"or 0..14)") from None
    if not 0 <= value <= 14:
        raise EtherCATConfigError(f"datagram command {value} is not 0..14")
    return value


def datagrams_of(frame: bytes | bytearray) -> list[tuple[int, int, int, int]] | None:
    """(offset of the datagram in ``frame``, command, address field, data length) of each datagram of an
    EtherCAT frame (the header layout of ``datagram.py``), or None for a frame that is not one."""
    n = len(frame)
    if n < ETH_HEADER_LEN + ECAT_HEADER_LEN or ETH_HEADER.unpack_from(frame, 0)[2] != ETHERTYPE_ETHERCAT:
        return None
    hdr = ECAT_HEADER.unpack_from(frame, ETH_HEADER_LEN)[0]
    end = ETH_HEADER_LEN + ECAT_HEADER_LEN + (hdr & LEN_MASK)
    if hdr >> 12 != ECAT_TYPE_DATAGRAMS or end > n:
        return None
    pos = ETH_HEADER_LEN + ECAT_HEADER_LEN
    out: list[tuple[int, int, int, int]] = []
    while pos + DATAGRAM_HEADER.size + WKC.size <= end:
        cmd, _idx, address, flags, _irq = DATAGRAM_HEADER.unpack_from(frame, pos)
        dlen = flags & LEN_MASK
        if pos + DATAGRAM_HEADER.size + dlen + WKC.size > end:
            return None
        out.append((pos, cmd, address, dlen))
        pos += DATAGRAM_HEADER.size + dlen + WKC.size
        if not flags & MORE:
            return out
    return None


@dataclass(frozen=True, slots=True)
class Match:
    """Which datagrams a fault hits; every filter given must hold (none given: every datagram)."""

    #: datagram commands (numbers), or None for any
    commands: frozenset[int] | None = None
    #: a configured station address: FPRD/FPWR/FPRW/FRMW datagrams with this ADP
    station: int | None = None
    #: a logical address range [start, end] (end included): LRD/LWR/LRW datagrams that overlap it
    logical: tuple[int, int] | None = None

    @property
    def everything(self) -> bool:
        """No filter: every frame matches (no need to look at its datagrams)."""
        return self.commands is None and self.station is None and self.logical is None

    def datagram(self, cmd: int, address: int, dlen: int) -> bool:
        """Whether a datagram (command, 32-bit address field, data length) matches."""
        if self.commands is not None and cmd not in self.commands:
            return False
        if self.station is not None and (cmd not in CONFIGURED_COMMANDS or address & 0xFFFF != self.station):
            return False
        if self.logical is not None:
            start, end = self.logical
            if cmd not in LOGICAL_COMMANDS or address > end or address + max(dlen, 1) - 1 < start:
                return False
        return True

    def describe(self) -> dict[str, Any]:
        """The filters as JSON-ready fields (what the board shows)."""
        out: dict[str, Any] = {}
        if self.commands is not None:
            out["cmd"] = [Command(c).name for c in sorted(self.commands)]
        if self.station is not None:
            out["station"] = self.station
        if self.logical is not None:
            out["logical"] = [self.logical[0], self.logical[1]]
        return out


#: the match of a fault without filters
ANY_DATAGRAM: Final = Match()


class Kind(enum.Enum):
    """What a line fault does to a frame."""

    LOSE = "lose"                 # the request never reaches the segment
    LOSE_REPLY = "lose-reply"     # processed, the reply lost
    CORRUPT = "corrupt"           # processed, the reply's FCS broken: the master's NIC drops it
    WKC = "wkc"                   # processed, an offset added to matching datagrams' WKC
    DELAY = "delay"               # processed, the reply sent later
    DUPLICATE = "duplicate"       # processed, the reply sent twice
    REORDER = "reorder"           # processed, the reply sent after the next one
    LINK_DOWN = "link-down"       # nothing passes


#: kinds that act before the segment sees the frame
_BEFORE: Final = frozenset({Kind.LOSE, Kind.LINK_DOWN})


class LineFault:
    """One armed fault: its kind, what it matches, how many frames (datagrams, for WKC) it has left."""

    def __init__(self, kind: Kind, match: Match = ANY_DATAGRAM, count: int | None = None, *, offset: int = 0,
                 delay_s: float = 0.0, jitter_s: float = 0.0, seed: int = 1, hold_s: float = REORDER_HOLD_S,
                 details: dict[str, Any] | None = None, on_end: Callable[[], None] | None = None) -> None:
        self.kind = kind
        self.match = match
        #: frames (datagrams for WKC) still to hit; None: until removed
        self.left = count
        self.offset = offset
        self.delay_s = delay_s
        self.jitter_s = jitter_s
        self.rng = random.Random(seed)
        #: reorder: the longest a reply waits for the next one
        self.hold_s = hold_s
        #: shown on the board as they are; "left" and "hits" follow the fault's progress
        self.details: dict[str, Any] = {} if details is None else details
        self.details.setdefault("hits", 0)
        if count is not None:
            self.details["left"] = count
        #: called once the count is used up (the rig ends the board entry with it)
        self.on_end = on_end

    def hits(self, frame: bytearray, dgrams: list[tuple[int, int, int, int]] | None) -> bool:
        """Whether the frame has a matching datagram (every frame when the fault has no filter)."""
        if self.match.everything:
            return True
        return dgrams is not None and any(self.match.datagram(c, a, n) for _p, c, a, n in dgrams)


class LineFaults:
    """The faults armed on one line, and the replies they hold back."""

    def __init__(self) -> None:
        self.faults: list[LineFault] = []
        #: replies held back: [due time, frame] in the order they leave
        self.held: list[tuple[float, bytes]] = []
        #: a reordered reply waiting for the next reply (an entry of ``held``), or None
        self._behind: tuple[float, bytes] | None = None
        #: a fault is armed or a reply is held: transports route frames through :meth:`serve`
        self.engaged = False
        #: frames that did not come back (lost either way, corrupted, link down) and replies held back
        self.lost = 0
        self.delayed = 0

    # -- arming -------------------------------------------------------------------------------------------
    def add(self, fault: LineFault) -> LineFault:
        """Arm ``fault``."""
        self.faults.append(fault)
        self.engaged = True
        return fault

    def remove(self, fault: LineFault) -> None:
        """Disarm ``fault`` (nothing when it is not armed); replies held back still leave when due."""
        if fault in self.faults:
            self.faults.remove(fault)
        self.engaged = bool(self.faults) or bool(self.held)

    def _hit(self, fault: LineFault, n: int = 1) -> None:
        """``fault`` hit ``n`` frames or datagrams; disarmed (and ``on_end`` called) once its count is used up."""
        fault.details["hits"] += n
        if fault.left is None:
            return
        fault.left = max(0, fault.left - n)
        fault.details["left"] = fault.left
        if fault.left == 0:
            self.remove(fault)
            if fault.on_end is not None:
                fault.on_end()

    # -- the frame path -----------------------------------------------------------------------------------
    def serve(self, segment: Segment, frame: bytearray, now: float, *, defer: bool = False) -> bool:
        """Pass ``frame`` through the armed faults and the segment (``Segment.process(frame, defer=defer)``);
        True when the transport sends the frame back now. Replies held back come out of :meth:`due`."""
        faults = tuple(self.faults)
        dgrams = datagrams_of(frame) if any(not f.match.everything for f in faults) else None
        for f in faults:
            if f.kind in _BEFORE and f.hits(frame, dgrams):
                self.lost += 1
                self._hit(f)
                return False
        if not segment.process(frame, defer=defer):
            return False
        for f in faults:
            kind = f.kind
            if kind is Kind.WKC:
                self._offset(f, frame, dgrams if dgrams is not None else datagrams_of(frame))
            elif kind in _BEFORE or f not in self.faults or not f.hits(frame, dgrams):
                continue
            elif kind is Kind.LOSE_REPLY or kind is Kind.CORRUPT:
                self.lost += 1
                self._hit(f)
                return False
            elif kind is Kind.DUPLICATE:
                self._hit(f)
                self.held.append((now, bytes(frame)))
                self.engaged = True     # a held reply keeps the line engaged once the fault is used up
            elif kind is Kind.REORDER and self._behind is None:
                self._hit(f)
                self._behind = (now + f.hold_s, bytes(frame))
                self.held.append(self._behind)
                self.engaged = True
                return False
            elif kind is Kind.DELAY:
                self._hit(f)
                self._hold(now + f.delay_s + (f.rng.uniform(0.0, f.jitter_s) if f.jitter_s > 0 else 0.0),
                           bytes(frame))
                return False
        self._release_behind(now)
        return True

    def _offset(self, fault: LineFault, frame: bytearray, dgrams: list[tuple[int, int, int, int]] | None) -> None:
        """Add the fault's offset to the WKC of each matching datagram, as many as it has left."""
        if dgrams is None or fault not in self.faults:
            return
        n = 0
        for pos, cmd, address, dlen in dgrams:
            if fault.left is not None and n >= fault.left:
                break
            if fault.match.datagram(cmd, address, dlen):
                at = pos + DATAGRAM_HEADER.size + dlen
                WKC.pack_into(frame, at, (WKC.unpack_from(frame, at)[0] + fault.offset) & 0xFFFF)
                n += 1
        if n:
            self._hit(fault, n)

    def _hold(self, due: float, reply: bytes) -> None:
        """Queue a delayed reply; it never overtakes one queued before it."""
        if self.held:
            due = max(due, self.held[-1][0])
        self.held.append((due, reply))
        self.delayed += 1
        self.engaged = True

    def _release_behind(self, now: float) -> None:
        """A reply goes out now: the reordered reply waiting for it follows it."""
        behind = self._behind
        if behind is not None:
            self._behind = None
            self.held = [(now, e[1]) if e is behind else e for e in self.held]
            self.engaged = True

    def due(self, now: float) -> list[bytes]:
        """The held replies whose time has come, in order (the transport sends them)."""
        if not self.held:
            return []
        out = [r for t, r in self.held if t <= now]
        if out:
            self.held = [e for e in self.held if e[0] > now]
            if self._behind is not None and self._behind not in self.held:
                self._behind = None
            self.engaged = bool(self.faults) or bool(self.held)
        return out

    def next_due(self) -> float | None:
        """When the next held reply is due, or None."""
        return min((t for t, _r in self.held), default=None)

    def serve_now(self, segment: Segment, frame: bytearray, now: float) -> bool:
        """:meth:`serve` for an in-process master, which takes a frame's own reply at once or never: a reply
        held back (delayed, reordered) is lost to it, and no extra copy (a duplicate) reaches it."""
        ok = self.serve(segment, frame, now)
        self.held.clear()
        self._behind = None
        self.engaged = bool(self.faults)
        return ok
