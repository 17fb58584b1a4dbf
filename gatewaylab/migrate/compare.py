"""``gatewaylab migrate compare``, the pure part: two recordings in, differences and latencies out.

A :class:`Recording` is what one run of an application through one gateway left behind: every frame
that completed on the CAN bus (its end-of-frame time) and the application's own events (each
``send()`` call with its call time, each received frame with the time the host handed it to
``recv()``). Times are seconds since the application started. :func:`compare` is a pure function of
two recordings (no rig, no clock, no files), so it is tested on hand-made traces; the runner
(:mod:`.compare_run`) records, :mod:`.compare_report` writes the traces and the report.

Traffic: the two bus frame sequences are aligned with :class:`difflib.SequenceMatcher` on the
frames' (identifier, flags, payload); what the alignment leaves over is classified as an *order*
difference (the same frame in both traces, at another place), a *payload* difference (the same
identifier with other data, at the same place) or a frame *only in one* trace. Timing never makes
traffic differ.

Latency: master -> CAN is a ``send()`` call to the end of that frame on the bus (the first frame
with its key at or after the call); CAN -> master is the end of a frame another node sent to the
moment the application could receive it.
"""

from __future__ import annotations

import difflib
import math
from collections import defaultdict, deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import Enum

#: At most this many differences of each kind are listed one by one in a report.
MAX_LISTED = 50


@dataclass(frozen=True, slots=True)
class Frame:
    """A CAN frame at time ``t`` (seconds since the application started)."""

    t: float
    can_id: int
    data: bytes
    extended: bool = False
    rtr: bool = False

    @property
    def key(self) -> tuple[int, bool, bool, bytes]:
        """What makes two frames 'the same frame' on a bus (time aside)."""
        return (self.can_id, self.extended, self.rtr, self.data)

    def label(self) -> str:
        """The frame as a report cell, candump-like: ``123 [2] 01 02``, ``R`` for a remote frame."""
        ident = f"{self.can_id:08X}" if self.extended else f"{self.can_id:03X}"
        body = "R" if self.rtr else (self.data.hex(" ").upper() or "-")
        return f"{ident} [{len(self.data)}] {body}"


class AppEventKind(Enum):
    """Whether the application sent a frame or was handed one (the JSON rows carry the value)."""

    SEND = "send"
    RECV = "recv"


@dataclass(frozen=True, slots=True)
class AppEvent:
    """The application's ``send()`` call (``t`` = call time) or a frame it received (``t`` = when
    the host handed it to ``recv()``)."""

    kind: AppEventKind
    frame: Frame


@dataclass(frozen=True, slots=True)
class Recording:
    """One run through one gateway: ``gateway`` is its display name ("esd CAN-EtherCAT")."""

    gateway: str
    bus: tuple[Frame, ...]
    app: tuple[AppEvent, ...] = ()
    #: simulated (or wall) seconds the application ran
    duration: float = 0.0


@dataclass(frozen=True, slots=True)
class Only:
    """A frame found in one trace only: ``index`` in that trace's bus frames."""

    side: int            # 0 = first recording, 1 = second
    index: int
    frame: Frame


@dataclass(frozen=True, slots=True)
class Moved:
    """The same frame in both traces at places the alignment could not match."""

    index_a: int
    index_b: int
    frame: Frame


@dataclass(frozen=True, slots=True)
class PayloadDiff:
    """The same identifier at aligned places with other data (or flags)."""

    index_a: int
    index_b: int
    a: Frame
    b: Frame


@dataclass(frozen=True, slots=True)
class Stats:
    """A latency distribution in seconds (nearest-rank percentiles)."""

    count: int
    p50: float
    p99: float
    max: float
    mean: float

    @classmethod
    def of(cls, values: Sequence[float]) -> Stats | None:
        """The distribution of ``values``, None when there are none (a report prints '-')."""
        if not values:
            return None
        s = sorted(values)
        return cls(len(s), percentile(s, 50), percentile(s, 99), s[-1], math.fsum(s) / len(s))


def percentile(sorted_values: Sequence[float], p: float) -> float:
    """Nearest-rank percentile of sorted values (the smallest value with at least p % at or below it)."""
    rank = max(1, math.ceil(p / 100 * len(sorted_values)))
    return sorted_values[rank - 1]


@dataclass(frozen=True, slots=True)
class Latencies:
    """Per-frame latencies of one recording; unmatched counts what found no partner."""

    to_can: tuple[float, ...]          # master -> CAN
    to_master: tuple[float, ...]       # CAN -> master
    unmatched_sends: int
    unmatched_recvs: int
    #: indexes of the bus frames the application sent (the rest came from other nodes)
    sent_by_app: frozenset[int]


@dataclass(frozen=True, slots=True)
class Comparison:
    """What :func:`compare` found between two recordings: the traffic differences and both latencies."""

    a: Recording
    b: Recording
    only: tuple[Only, ...]
    moved: tuple[Moved, ...]
    payload: tuple[PayloadDiff, ...]
    latency_a: Latencies
    latency_b: Latencies

    @property
    def identical(self) -> bool:
        """The CAN traffic is the same (timing aside)."""
        return not (self.only or self.moved or self.payload)

    def only_in(self, side: int) -> tuple[Only, ...]:
        """The frames found only in recording ``side`` (0 = a, 1 = b)."""
        return tuple(o for o in self.only if o.side == side)

    def verdict(self) -> str:
        """One line: same or different traffic, and the latency medians."""
        a, b = self.a.gateway, self.b.gateway
        if self.identical:
            head = f"identical CAN traffic: {len(self.a.bus)} frames through both gateways"
        else:
            head = (f"CAN traffic differs: {len(self.only_in(0))} frames only through {a}, "
                    f"{len(self.only_in(1))} only through {b}, {len(self.moved)} in another order, "
                    f"{len(self.payload)} with other payload")
        parts = []
        for name, lat in ((a, self.latency_a), (b, self.latency_b)):
            up, down = Stats.of(lat.to_can), Stats.of(lat.to_master)
            parts.append(f"{name} p50 {ms(up.p50 if up else None)} / {ms(down.p50 if down else None)}")
        return f"{head}; master->CAN / CAN->master: " + ", ".join(parts)


@dataclass(frozen=True, slots=True)
class IdSummary:
    """The differences of one identifier; ``sender`` says who sent its frames in the traces."""

    can_id: int
    extended: bool
    only_a: int
    only_b: int
    moved: int
    payload: int
    sender: str          # "application", "other nodes" or "both"

    def label(self) -> str:
        """The identifier as a report cell (eight hex digits when extended, three otherwise)."""
        return f"{self.can_id:08X}" if self.extended else f"{self.can_id:03X}"


def by_identifier(c: Comparison) -> tuple[IdSummary, ...]:
    """The differences grouped by identifier (in identifier order): whether the application's own
    frames differ or only what other nodes sent back."""
    counts: dict[tuple[int, bool], list[int]] = defaultdict(lambda: [0, 0, 0, 0])
    senders: dict[tuple[int, bool], set[bool]] = defaultdict(set)

    def note(key: tuple[int, bool], slot: int, side: int, index: int) -> None:
        counts[key][slot] += 1
        lat = c.latency_a if side == 0 else c.latency_b
        senders[key].add(index in lat.sent_by_app)

    for o in c.only:
        note((o.frame.can_id, o.frame.extended), o.side, o.side, o.index)
    for m in c.moved:
        note((m.frame.can_id, m.frame.extended), 2, 0, m.index_a)
    for p in c.payload:
        note((p.a.can_id, p.a.extended), 3, 0, p.index_a)
    out = []
    for key in sorted(counts, key=lambda k: (k[1], k[0])):
        who = senders[key]
        sender = "both" if len(who) == 2 else ("application" if True in who else "other nodes")
        only_a, only_b, moved, payload = counts[key]
        out.append(IdSummary(key[0], key[1], only_a, only_b, moved, payload, sender))
    return tuple(out)


def ms(value: float | None) -> str:
    """Seconds as milliseconds with three decimals (one microsecond), '-' for none."""
    return "-" if value is None else f"{value * 1e3:.3f} ms"


def latencies(rec: Recording) -> Latencies:
    """Match the application's events to the bus frames by frame key, first come first served.

    A ``send()`` takes the first unmatched bus frame with its key that ended at or after the call;
    a received frame takes the first unmatched bus frame with its key, not sent by the
    application, that ended at or before the reception."""
    by_key: dict[tuple[int, bool, bool, bytes], list[int]] = defaultdict(list)
    for i, f in enumerate(rec.bus):
        by_key[f.key].append(i)
    used: set[int] = set()
    sent: set[int] = set()
    to_can: list[float] = []
    to_master: list[float] = []
    lost_sends = lost_recvs = 0
    sends = [e for e in rec.app if e.kind is AppEventKind.SEND]
    for ev in sends:
        match = next((i for i in by_key.get(ev.frame.key, ()) if i not in used and rec.bus[i].t >= ev.frame.t), None)
        if match is None:
            lost_sends += 1
            continue
        used.add(match)
        sent.add(match)
        to_can.append(rec.bus[match].t - ev.frame.t)
    for ev in (e for e in rec.app if e.kind is AppEventKind.RECV):
        match = next((i for i in by_key.get(ev.frame.key, ()) if i not in used and rec.bus[i].t <= ev.frame.t), None)
        if match is None:
            lost_recvs += 1
            continue
        used.add(match)
        to_master.append(ev.frame.t - rec.bus[match].t)
    return Latencies(tuple(to_can), tuple(to_master), lost_sends, lost_recvs, frozenset(sent))


def _align(a: Sequence[Frame], b: Sequence[Frame]) -> tuple[list[Only], list[Moved], list[PayloadDiff]]:
    ka = [f.key for f in a]
    kb = [f.key for f in b]
    left_a: list[int] = []
    left_b: list[int] = []
    blocks: list[tuple[list[int], list[int]]] = []
    for tag, i1, i2, j1, j2 in difflib.SequenceMatcher(None, ka, kb, autojunk=False).get_opcodes():
        if tag == "equal":
            continue
        blocks.append((list(range(i1, i2)), list(range(j1, j2))))
        left_a.extend(range(i1, i2))
        left_b.extend(range(j1, j2))
    # 1. the same frame elsewhere in the other trace: an order difference
    free_b: dict[tuple[int, bool, bool, bytes], deque[int]] = defaultdict(deque)
    for j in left_b:
        free_b[kb[j]].append(j)
    moved: list[Moved] = []
    paired_a: set[int] = set()
    paired_b: set[int] = set()
    for i in left_a:
        q = free_b.get(ka[i])
        if q:
            j = q.popleft()
            moved.append(Moved(i, j, a[i]))
            paired_a.add(i)
            paired_b.add(j)
    # 2. in one replaced block, the same identifier with other data: a payload difference
    payload: list[PayloadDiff] = []
    for ia, jb in blocks:
        rest_b = [j for j in jb if j not in paired_b]
        for i in ia:
            if i in paired_a:
                continue
            hit = next((j for j in rest_b if (b[j].can_id, b[j].extended) == (a[i].can_id, a[i].extended)), None)
            if hit is None:
                continue
            rest_b.remove(hit)
            payload.append(PayloadDiff(i, hit, a[i], b[hit]))
            paired_a.add(i)
            paired_b.add(hit)
    # 3. the rest is in one trace only
    only = [Only(0, i, a[i]) for i in left_a if i not in paired_a]
    only += [Only(1, j, b[j]) for j in left_b if j not in paired_b]
    return only, moved, payload


def compare(a: Recording, b: Recording) -> Comparison:
    """Differences between the bus traffic of two recordings and each one's latencies."""
    only, moved, payload = _align(a.bus, b.bus)
    return Comparison(a, b, tuple(only), tuple(sorted(moved, key=lambda m: m.index_a)),
                      tuple(payload), latencies(a), latencies(b))


def frames(items: Iterable[tuple[float, int, bytes]]) -> tuple[Frame, ...]:
    """Frames from (t, id, data) triples: hand-made traces in tests and docs."""
    return tuple(Frame(t, i, bytes(d)) for t, i, d in items)


__all__ = ["MAX_LISTED", "AppEvent", "AppEventKind", "Comparison", "Frame", "IdSummary", "Latencies", "Moved",
           "Only", "PayloadDiff", "Recording", "Stats", "by_identifier", "compare", "frames", "latencies", "ms",
           "percentile"]
