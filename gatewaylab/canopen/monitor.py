"""A sans-I/O CANopen bus monitor: frames in, decoded events and a per-node view out.

What a CANopen analyser (CANopen Magic, PCAN-View's CANopen add-in, Wireshark's dissector) shows:
SDO transfers reassembled into one line each (expedited, segmented and block, aborts by name),
PDOs with their mapped values where the node's dictionary is known (an EDS, or the rig's
drives), NMT, SYNC, TIME, heartbeat and boot-up, EMCY with the error code's name, LSS with
Fastscan told as the bisection it is. Every single frame is described by :func:`.explain.explain`
(the decoder of ``make demo``): this module only adds what needs more than one frame.

The monitor learns PDO mappings as they change: a completed SDO download to a communication or
mapping parameter (0x1400-0x1BFF) of a known node updates its copy of the dictionary.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from gatewaylab.bus.candump import long_frame
from gatewaylab.bus.errorframe import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_RX_PASSIVE,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_RESTARTED,
    ErrorFrame,
    summary,
)
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.signals import DecodedMessage
from gatewaylab.bus.timing import frame_duration
from gatewaylab.canopen.cia402 import OpMode, state_from_statusword
from gatewaylab.canopen.emcy import error_code_name
from gatewaylab.canopen.explain import explain, time_of_day
from gatewaylab.canopen.lss import FASTSCAN_CONFIRM, Cs
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.od import ObjectDictionary
from gatewaylab.od.aborts import SdoAbort, abort_text
from gatewaylab.od.types import Entry, decode

__all__ = [
    "BusMonitor",
    "ControllerWatch",
    "FastscanNarrator",
    "MonitorEvent",
    "NodeView",
    "SignalSource",
    "hex_at_width",
]


_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_LSS_PARTS = ("vendor", "product", "revision", "serial")
#: Objects whose value the node table shows (CiA 402), by (index, subindex) -> NodeView field.
#: NMT states a heartbeat carries (CiA 301 7.2.8.3.2.1): boot-up, stopped, operational, pre-operational.
_HEARTBEAT_STATES = frozenset((0x00, 0x04, 0x05, 0x7F))
#: 0x6060 (modes of operation) fills the mode until the display (0x6061) is seen.
_VIEW_FIELDS = {(0x6041, 0): "statusword", (0x6060, 0): "mode", (0x6061, 0): "mode", (0x6064, 0): "position",
                (0x606C, 0): "velocity"}


class SignalSource(Protocol):
    """A signal database (bus/signals.py SignalDecoder): the frames it defines, decoded."""

    def decode(self, frame: CanFrame) -> DecodedMessage | None:
        """The frame decoded into its signals, or None when the database does not define it."""


@dataclass(frozen=True, slots=True)
class MonitorEvent:
    """One line of the decoded log; ``fields`` carries the same facts for ``--json``."""

    t: float
    #: sdo, sdo-abort, pdo, nmt, sync, time, heartbeat, boot-up, emcy, lss, frame (raw), bus (error
    #: frames, controller states), node (a node left), ethercat, can (rig controllers), signal (--db),
    #: undecodable (--db: a frame of a database id that does not fit its message); docs/monitor.md
    kind: str
    text: str
    node: int | None = None
    fields: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The event as a JSON-able dict (one object per line in ``gatewaylab monitor --json``)."""
        return {"t": round(self.t, 6), "kind": self.kind, "node": self.node, "text": self.text, **self.fields}


@dataclass(slots=True)
class NodeView:
    """What the monitor knows of one node (the node table)."""

    node_id: int
    nmt: str = "?"
    heartbeat_t: float | None = None
    statusword: int | None = None
    mode: int | None = None
    position: int | None = None
    velocity: int | None = None
    emcy: str | None = None
    emcy_t: float | None = None
    #: time between its last two heartbeats, and whether it went silent since (BusMonitor.tick)
    period: float | None = None
    silent: bool = False

    @property
    def cia402_state(self) -> str:
        """The CiA 402 power state the statusword says (empty when unknown)."""
        if self.statusword is None:
            return ""
        state = state_from_statusword(self.statusword)
        return state.value.lower() if state is not None else "?"

    @property
    def mode_name(self) -> str:
        """Mode of operation display as a name (CiA 402 0x6061)."""
        if self.mode is None:
            return ""
        try:
            return OpMode(self.mode).name
        except ValueError:
            return str(self.mode)


@dataclass(slots=True)
class _Transfer:
    """An SDO transfer in progress between the client and server of one node."""

    t0: float
    upload: bool
    index: int
    subindex: int
    mode: str                      # expedited, segmented, block
    size: int | None = None
    data: bytearray = field(default_factory=bytearray)
    segments: int = 0
    #: what comes next: "init" (initiate response), "segments", "end" (block end), "last" (confirm)
    phase: str = "init"
    pending: bytes = b""           # an expedited download's value until the server confirms
    #: block transfer: segments of the current sub-block as (data, last) until acknowledged
    sub: list[tuple[bytes, bool]] = field(default_factory=list)
    unused: int = 0                # block: bytes of the last segment that carry no data

    def acknowledge(self, ackseq: int) -> None:
        """A block sub-block acknowledged up to ``ackseq``: those segments are data, the rest is
        sent again (CiA 301 7.2.4.3.10); after the last one the end follows."""
        for data, last in self.sub[:ackseq]:
            self.data += data
            self.segments += 1
            if last:
                self.phase = "end"
        self.sub.clear()

    def block_data(self) -> bytes:
        data = bytes(self.data[:len(self.data) - self.unused])
        return data[:self.size] if self.size is not None else data


@dataclass(frozen=True, slots=True)
class _Mapped:
    index: int
    subindex: int
    bits: int
    entry: Entry | None


class FastscanNarrator:
    """Turns Fastscan requests and answers into the bisection they are ("bit 27 of serial: 0").

    A request with BitChecked b asks "does any non-configured slave match the bits above b?"; an
    answer means bit b is 0 (it was sent as 0), silence until the next request that it is 1
    (CiA 305 clause 8.3.5)."""

    def __init__(self, say: Callable[[int, int, int], None]) -> None:
        self._say = say                                # (lss_sub, bit, value told)
        self._pending: tuple[int, int] | None = None   # (lss_sub, bit) asked, not answered yet

    def request(self, data: bytes) -> None:
        """A frame the LSS master sent on 0x7E5."""
        self.flush()
        if len(data) == 8 and data[0] == Cs.FASTSCAN and data[5] != FASTSCAN_CONFIRM and data[6] == data[7] \
                and data[5] < 32 and data[6] < 4:
            self._pending = (data[6], data[5])

    def answer(self) -> None:
        """An identify-slave answer on 0x7E4: the bit asked is 0."""
        if self._pending is not None:
            sub, bit = self._pending
            self._pending = None
            self._say(sub, bit, 0)

    def flush(self) -> None:
        """No answer came before the next request (or the end): the bit asked is 1."""
        if self._pending is not None:
            sub, bit = self._pending
            self._pending = None
            self._say(sub, bit, 1)


def hex_at_width(value: int, size: int | None) -> str:
    """``value`` in hex at its own width: ``size`` bytes (the dictionary's type), or the smallest
    of 1, 2, 4, 8 bytes that holds it; a negative number in two's complement of that width
    (an INTEGER32 -60000 is 0xFFFF15A0, not a 64-bit pattern)."""
    if size is None or size <= 0:
        size = next((n for n in (1, 2, 4, 8) if -(1 << (8 * n - 1)) <= value < (1 << (8 * n))), 8)
    return f"0x{value & ((1 << (8 * size)) - 1):0{2 * size}X}"


def _value_text(value: Any, size: int | None = None) -> str:
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return f"{value} ({hex_at_width(value, size)})" if value > 9 or value < 0 else str(value)
    if isinstance(value, (bytes, bytearray)):
        head = bytes(value[:16]).hex(" ")
        return head if len(value) <= 16 else f"{head} ... ({len(value)} bytes)"
    return str(value)


def _raw_value(data: bytes) -> Any:
    """A value without a dictionary: little-endian integer up to 4 bytes, text if printable, else bytes."""
    if 0 < len(data) <= 4:
        return int.from_bytes(data, "little")
    if data and all(32 <= b < 127 for b in data.rstrip(b"\x00")):
        return data.rstrip(b"\x00").decode("ascii")
    return bytes(data)


class BusMonitor:
    """Feed every frame of a bus (``feed``); read the log events it returns and ``nodes``."""

    def __init__(self, dictionaries: Mapping[int, ObjectDictionary] | None = None, bitrate: int = 1_000_000,
                 data_bitrate: int | None = None, window: float = 1.0, known: Iterable[int] = (),
                 silence: float = 0.5, signals: SignalSource | None = None) -> None:
        #: node-id -> its dictionary (a copy the monitor updates from observed SDO writes)
        self.dictionaries: dict[int, ObjectDictionary] = dict(dictionaries or {})
        self.nodes: dict[int, NodeView] = {}
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate
        #: a signal database (``--db``, bus/signals.py): the frames it defines are decoded by it first
        self.signals = signals
        self.frames = 0
        self.error_frames = 0
        #: the monitor's own controller as its last state-change error frame said
        self.bus_state = "error-active"
        #: the shortest silence after which a node with a heartbeat counts as gone (tick)
        self.silence = silence
        self.window = window
        self._recent: deque[tuple[float, float]] = deque()   # (t, bus time the frame took)
        self._busy = 0.0
        self._transfers: dict[int, _Transfer] = {}
        self._pdos: dict[int, tuple[int, str, tuple[_Mapped, ...]]] = {}
        self._lss_events: list[MonitorEvent] = []
        self._lss_t = 0.0
        self._fastscan = FastscanNarrator(self._fastscan_step)
        for node_id in self.dictionaries:
            self._map_pdos(node_id)
        for node_id in (*self.dictionaries, *known):   # listed before they speak
            self.node(node_id)

    # -- statistics ------------------------------------------------------------------------------
    def load_percent(self) -> float:
        """Bus load over the last ``window`` seconds of bus time (bit-count model of docs/bus.md)."""
        return 100.0 * self._busy / self.window

    def frames_per_second(self) -> float:
        """Frames per second over the last ``window`` seconds."""
        return len(self._recent) / self.window

    def _count(self, frame: CanFrame, t: float) -> None:
        self.frames += 1
        busy = frame_duration(frame, self.bitrate, self.data_bitrate)
        self._recent.append((t, busy))
        self._busy += busy
        horizon = t - self.window
        while self._recent and self._recent[0][0] < horizon:
            self._busy -= self._recent.popleft()[1]

    def node(self, node_id: int) -> NodeView:
        """The view of ``node_id`` (created when first seen)."""
        view = self.nodes.get(node_id)
        if view is None:
            view = self.nodes[node_id] = NodeView(node_id)
        return view

    # -- decoding --------------------------------------------------------------------------------
    def feed(self, frame: CanFrame, t: float) -> list[MonitorEvent]:
        """Decode one frame seen on the bus at bus time ``t``; returns the log events it completes.

        An identifier gets its CANopen meaning only when the frame fits it: the right length, and
        for a node's own objects (PDO, EMCY) a node the monitor knows (a dictionary, the rig's list,
        a heartbeat or an SDO seen). Anything else is shown raw, as candump prints it."""
        self._count(frame, t)
        if self.signals is not None:
            message = self.signals.decode(frame)
            if message is not None and message.error:     # the database's id, not its layout
                return [MonitorEvent(t, "undecodable", f"{long_frame(frame)}   ({message.text()})", None,
                                     {"id": frame.can_id, "extended": frame.extended, "data": frame.data.hex(),
                                      "message": message.name, "reason": message.error})]
            if message is not None:
                return [MonitorEvent(t, "signal", message.text(), None,
                                     {"id": frame.can_id, "extended": frame.extended, "message": message.name,
                                      "signals": {n: v for n, v, _ in message.signals}})]
        cid, d = frame.can_id, frame.data
        if frame.extended or frame.fd or frame.rtr:
            return [self._raw(frame, t, explain(frame) if frame.rtr and not frame.extended else "")]
        if 0x581 <= cid <= 0x5FF and len(d) == 8:
            return self._sdo(cid - 0x580, d, t, request=False)
        if 0x601 <= cid <= 0x67F and len(d) == 8:
            return self._sdo(cid - 0x600, d, t, request=True)
        pdo = self._pdos.get(cid)
        if pdo is not None:
            return [self._pdo(pdo, d, t)]
        if cid == 0x000 and len(d) == 2:
            return self._nmt(d, frame, t)
        if cid == 0x080 and len(d) <= 1:
            return [MonitorEvent(t, "sync", explain(frame), None, {"counter": d[0]} if d else {})]
        if 0x081 <= cid <= 0x0FF and len(d) == 8 and cid - 0x80 in self.nodes:
            return [self._emcy(cid - 0x80, d, t)]
        if cid == 0x100 and len(d) == 6:
            when = time_of_day(d)
            return [MonitorEvent(t, "time", f"TIME {when.isoformat(timespec='milliseconds')}", None,
                                 {"time": when.isoformat()})]
        if 0x701 <= cid <= 0x77F and len(d) == 1 and (d[0] & 0x7F) in _HEARTBEAT_STATES:
            return [self._heartbeat(cid - 0x700, d[0], frame, t)]
        if cid in (0x7E4, 0x7E5) and len(d) == 8:
            return self._lss(cid, d, frame, t)
        if 0x181 <= cid <= 0x57F and (cid & 0x7F) in self.nodes and (cid & 0x7F):
            return [self._raw(frame, t, explain(frame).split(":")[0], cid & 0x7F)]
        return [self._raw(frame, t)]

    def _raw(self, frame: CanFrame, t: float, note: str = "", node: int | None = None) -> MonitorEvent:
        """A frame without a CANopen meaning here: its candump line (and what it may be)."""
        text = long_frame(frame) + (f"   ({note})" if note else "")
        return MonitorEvent(t, "frame", text, node, {"id": frame.can_id, "extended": frame.extended,
                                                      "data": frame.data.hex()})

    def feed_error(self, error: ErrorFrame, t: float) -> list[MonitorEvent]:
        """An error frame or a controller state change the monitor's controller saw (SocketCAN
        layout, bus/errorframe.py): one ``bus`` event, and the bus state of the header."""
        self.error_frames += 1
        text = summary(error)
        cls = error.can_id
        if cls & (CAN_ERR_BUSOFF | CAN_ERR_CRTL | CAN_ERR_RESTARTED):
            self.bus_state = ("bus-off" if cls & CAN_ERR_BUSOFF else
                              "error-passive" if error.data[1] & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)
                              else "error-active")
        return [MonitorEvent(t, "bus", text, None, {"class": cls, "data": error.data.hex(),
                                                   "tec": error.tec, "rec": error.rec})]

    def tick(self, now: float) -> list[MonitorEvent]:
        """Nodes whose heartbeat stopped: silent for more than three of their periods (at least
        ``silence`` seconds), once per silence; their NMT column says "silent"."""
        events = []
        for view in self.nodes.values():
            if view.heartbeat_t is None or view.period is None or view.silent:
                continue
            limit = max(3 * view.period, self.silence)
            if now - view.heartbeat_t > limit:
                view.silent = True
                view.nmt = "silent"
                gap = now - view.heartbeat_t
                events.append(MonitorEvent(now, "node", f"node {view.node_id} left the bus: no heartbeat for "
                                           f"{gap:.2f} s (period {view.period * 1000:.0f} ms)",
                                           view.node_id, {"event": "left", "silent_s": round(gap, 3)}))
        return events

    def feed_many(self, frames: Iterable[tuple[CanFrame, float]]) -> list[MonitorEvent]:
        """Decode a recorded trace; returns every event in order."""
        out: list[MonitorEvent] = []
        for frame, t in frames:
            out.extend(self.feed(frame, t))
        return out

    def _nmt(self, d: bytes, frame: CanFrame, t: float) -> list[MonitorEvent]:
        target = d[1]
        new = {0x01: NmtState.OPERATIONAL, 0x02: NmtState.STOPPED, 0x80: NmtState.PRE_OPERATIONAL}.get(d[0])
        for view in ([self.node(target)] if target else list(self.nodes.values())):
            view.nmt = new.label if new is not None else "resetting"
        return [MonitorEvent(t, "nmt", explain(frame), target or None, {"command": d[0]})]

    def _heartbeat(self, node_id: int, state: int, frame: CanFrame, t: float) -> MonitorEvent:
        view = self.node(node_id)
        back = view.silent
        if view.heartbeat_t is not None and state != 0:
            view.period = t - view.heartbeat_t
        view.heartbeat_t = t
        view.silent = False
        if back:
            view.period = None
        again = f"node {node_id} is back: " if back else ""
        if state == 0:
            view.nmt = NmtState.PRE_OPERATIONAL.label   # boot-up: the node is in pre-operational
            return MonitorEvent(t, "boot-up", again + explain(frame), node_id)
        view.nmt = NmtState(state & 0x7F).label
        return MonitorEvent(t, "heartbeat", again + explain(frame), node_id, {"state": view.nmt, "back": back})

    def _emcy(self, node_id: int, d: bytes, t: float) -> MonitorEvent:
        code = _U16.unpack_from(d)[0]
        register = d[2] if len(d) > 2 else 0
        name = error_code_name(code)
        view = self.node(node_id)
        view.emcy, view.emcy_t = f"0x{code:04X} {name}", t
        return MonitorEvent(t, "emcy", f"EMCY node {node_id}: 0x{code:04X} {name}, error register 0x{register:02X}",
                            node_id, {"code": code, "name": name, "register": register})

    # -- LSS -------------------------------------------------------------------------------------
    def _fastscan_step(self, sub: int, bit: int, value: int) -> None:
        self._lss_events.append(MonitorEvent(self._lss_t, "lss", f"LSS Fastscan: bit {bit} of {_LSS_PARTS[sub]}: "
                                             f"{value}", None, {"part": _LSS_PARTS[sub], "bit": bit,
                                                                "value": value}))

    def _lss(self, cid: int, d: bytes, frame: CanFrame, t: float) -> list[MonitorEvent]:
        self._lss_t = t
        line = MonitorEvent(t, "lss", explain(frame))
        if cid == 0x7E5:
            self._fastscan.request(d)          # tells a bit the previous request left unanswered (1)
            events, self._lss_events = self._lss_events, []
            return [*events, line]
        if d[0] == Cs.IDENTIFY_SLAVE:
            self._fastscan.answer()            # the bit just asked is 0
        events, self._lss_events = self._lss_events, []
        return [line, *events]

    # -- PDO -------------------------------------------------------------------------------------
    def _map_pdos(self, node_id: int) -> None:
        """(Re)build the COB-ID -> mapping table of one node from its dictionary."""
        od = self.dictionaries[node_id]
        self._pdos = {cid: v for cid, v in self._pdos.items() if v[0] != node_id}
        values = od.values
        for comm, mapping, name in ((0x1800, 0x1A00, "TPDO"), (0x1400, 0x1600, "RPDO")):
            for n in range(512):
                cob = values.get((comm + n, 1))
                if cob is None:
                    break
                if cob & 0x80000000 or cob & 0x20000000:
                    continue   # invalid (CiA 301 COB-ID bit 31) or extended
                count = values.get((mapping + n, 0), 0) or 0
                entries = []
                for sub in range(1, count + 1):
                    word = values.get((mapping + n, sub), 0) or 0
                    index, subindex, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
                    entries.append(_Mapped(index, subindex, bits, od.entries.get((index, subindex))))
                self._pdos[cob & 0x7FF] = (node_id, f"{name}{n + 1}", tuple(entries))

    def _pdo(self, pdo: tuple[int, str, tuple[_Mapped, ...]], d: bytes, t: float) -> MonitorEvent:
        node_id, name, entries = pdo
        bits = int.from_bytes(d, "little")
        offset = 0
        parts: list[str] = []
        values: dict[str, Any] = {}
        view = self.node(node_id)
        for m in entries:
            raw = (bits >> offset) & ((1 << m.bits) - 1)
            offset += m.bits
            value: Any = raw
            if m.entry is not None and m.entry.size is not None and m.entry.size * 8 == m.bits:
                try:
                    value = decode(m.entry, raw.to_bytes(m.entry.size, "little"))
                except (SdoAbort, ValueError):   # outside the entry's limits: show it raw
                    value = raw
            label = m.entry.name if m.entry is not None else f"0x{m.index:04X}:{m.subindex:02X}"
            parts.append(f"{label}={_value_text(value, (m.bits + 7) // 8)}")
            values[f"0x{m.index:04X}:{m.subindex:02X}"] = value if not isinstance(value, bytes) else value.hex()
            if name.startswith("T"):
                self._view_update(view, m.index, m.subindex, value)
        if offset > 8 * len(d):
            return MonitorEvent(t, "pdo", f"{name} node {node_id}: {d.hex(' ')} (shorter than its mapping: "
                                f"{offset} bits)", node_id, {"pdo": name, "data": d.hex()})
        text = f"{name} node {node_id}: " + (", ".join(parts) if parts else d.hex(" "))
        return MonitorEvent(t, "pdo", text, node_id, {"pdo": name, "values": values})

    @staticmethod
    def _view_update(view: NodeView, index: int, subindex: int, value: Any) -> None:
        attr = _VIEW_FIELDS.get((index, subindex))
        if attr is not None and isinstance(value, int):
            setattr(view, attr, value)

    # -- SDO -------------------------------------------------------------------------------------
    def _describe(self, node_id: int, index: int, subindex: int) -> tuple[str, Entry | None]:
        od = self.dictionaries.get(node_id)
        entry = od.entries.get((index, subindex)) if od is not None else None
        where = f"0x{index:04X}:{subindex:02X}"
        if od is not None:
            obj = od.objects.get(index)
            if entry is not None and obj is not None and len(obj.entries) > 1:
                where += f" {obj.name}/{entry.name}"
            elif entry is not None:
                where += f" {entry.name}"
        return where, entry

    def _done(self, node_id: int, tr: _Transfer, t: float, data: bytes) -> MonitorEvent:
        self._transfers.pop(node_id, None)
        where, entry = self._describe(node_id, tr.index, tr.subindex)
        value: Any
        try:
            value = decode(entry, data) if entry is not None else _raw_value(data)
        except (SdoAbort, ValueError):   # the bytes do not fit the dictionary's type: show them
            value = bytes(data)
        if entry is None and isinstance(value, int) and len(data) > 4:
            value = bytes(data)
        how = tr.mode if tr.mode == "expedited" else f"{tr.mode}, {tr.segments} segment{'s' * (tr.segments != 1)}"
        ms = (t - tr.t0) * 1000
        verb = "read" if tr.upload else "write"
        size = entry.size if entry is not None and entry.size else len(data) or None
        text = f"node {node_id} {verb} {where} = {_value_text(value, size)} ({how}, {ms:.1f} ms)"
        if isinstance(value, int) and not tr.upload:
            self._learn(node_id, tr.index, tr.subindex, value)
        self._view_update(self.node(node_id), tr.index, tr.subindex, value)
        shown = value.hex() if isinstance(value, (bytes, bytearray)) else value
        return MonitorEvent(t, "sdo", text, node_id, {"op": verb, "index": tr.index, "subindex": tr.subindex,
                                                     "value": shown, "mode": tr.mode, "segments": tr.segments,
                                                     "ms": round(ms, 3)})

    def _learn(self, node_id: int, index: int, subindex: int, value: int) -> None:
        """A confirmed SDO write to a PDO parameter of a known node changes how its PDOs decode."""
        od = self.dictionaries.get(node_id)
        if od is None or not 0x1400 <= index <= 0x1BFF or (index, subindex) not in od.values:
            return
        od.values[(index, subindex)] = value
        self._map_pdos(node_id)

    def _abort(self, node_id: int, d: bytes, t: float, by: str) -> MonitorEvent:
        tr = self._transfers.pop(node_id, None)
        index, subindex = _U16.unpack_from(d, 1)[0], d[3]
        code = _U32.unpack_from(d, 4)[0]
        where, _ = self._describe(node_id, index, subindex)
        verb = ("read" if tr.upload else "write") if tr is not None else "transfer"
        text = f"node {node_id} {verb} {where} aborted by the {by}: {abort_text(code)} (0x{code:08X})"
        return MonitorEvent(t, "sdo-abort", text, node_id, {"index": index, "subindex": subindex, "code": code,
                                                           "by": by, "reason": abort_text(code)})

    def _sdo(self, node_id: int, d: bytes, t: float, request: bool) -> list[MonitorEvent]:
        if len(d) != 8:
            return [MonitorEvent(t, "frame", f"SDO with {len(d)} bytes for node {node_id} (CiA 301 needs 8)",
                                 node_id)]
        cmd = d[0]
        if cmd == 0x80:
            return [self._abort(node_id, d, t, "client" if request else "server")]
        tr = self._transfers.get(node_id)
        if request:
            return self._client(node_id, tr, d, t)
        return self._server(node_id, tr, d, t)

    def _other(self, node_id: int, cob: int, d: bytes, t: float) -> list[MonitorEvent]:
        return [MonitorEvent(t, "frame", f"node {node_id}: {explain(CanFrame(cob, d))}", node_id)]

    def _client(self, node_id: int, tr: _Transfer | None, d: bytes, t: float) -> list[MonitorEvent]:
        """A frame from the SDO client (0x600 + node); CiA 301 7.2.4.3."""
        cmd = d[0]
        cs = cmd >> 5
        index, subindex = _U16.unpack_from(d, 1)[0], d[3]
        if tr is not None and tr.mode == "block" and not tr.upload and tr.phase == "segments":
            tr.sub.append((bytes(d[1:8]), bool(cmd & 0x80)))   # seqno | last, 7 data bytes
            return []
        if cs == 1:   # initiate download
            if cmd & 0x02:
                n = 4 - ((cmd >> 2) & 3) if cmd & 0x01 else 4
                self._transfers[node_id] = _Transfer(t, False, index, subindex, "expedited", n,
                                                     pending=bytes(d[4:4 + n]))
            else:
                size = _U32.unpack_from(d, 4)[0] if cmd & 0x01 else None
                self._transfers[node_id] = _Transfer(t, False, index, subindex, "segmented", size)
            return []
        if cs == 2:   # initiate upload
            self._transfers[node_id] = _Transfer(t, True, index, subindex, "expedited")
            return []
        if cs == 0 and tr is not None and not tr.upload and tr.phase == "segments":   # download segment
            n = (cmd >> 1) & 7
            tr.data += d[1:8 - n]
            tr.segments += 1
            if cmd & 0x01:
                tr.phase = "last"
            return []
        if cs == 3 and tr is not None and tr.upload:   # upload segment request
            return []
        if cs == 6:   # block download: initiate (cs bit 0 = 0) or end (1)
            if cmd & 0x01 == 0:
                size = _U32.unpack_from(d, 4)[0] if cmd & 0x02 else None
                self._transfers[node_id] = _Transfer(t, False, index, subindex, "block", size)
            elif tr is not None and tr.mode == "block" and tr.phase == "end":
                tr.unused = (cmd >> 2) & 7
                tr.phase = "last"
            return []
        if cs == 5:   # block upload: initiate 0, end 1, ack 2, start 3
            sub = cmd & 0x03
            if sub == 0:
                self._transfers[node_id] = _Transfer(t, True, index, subindex, "block")
            elif sub == 2 and tr is not None and tr.upload and tr.mode == "block":
                tr.acknowledge(d[1])
            elif sub == 1 and tr is not None and tr.upload and tr.phase == "last":
                return [self._done(node_id, tr, t, tr.block_data())]
            return []
        return self._other(node_id, 0x600 + node_id, d, t)

    def _server(self, node_id: int, tr: _Transfer | None, d: bytes, t: float) -> list[MonitorEvent]:
        """A frame from the SDO server (0x580 + node); CiA 301 7.2.4.3."""
        cmd = d[0]
        cs = cmd >> 5
        if tr is None:
            return self._other(node_id, 0x580 + node_id, d, t)
        if tr.upload and tr.mode == "block" and tr.phase == "segments":
            tr.sub.append((bytes(d[1:8]), bool(cmd & 0x80)))
            return []
        if not tr.upload:
            if tr.mode == "expedited" and cs == 3:            # download confirmed
                return [self._done(node_id, tr, t, tr.pending)]
            if tr.mode == "segmented" and cs == 3:            # initiate confirmed: segments follow
                tr.phase = "segments"
                return []
            if tr.mode == "segmented" and cs == 1:            # a segment confirmed
                return [self._done(node_id, tr, t, bytes(tr.data))] if tr.phase == "last" else []
            if tr.mode == "block" and cs == 5:
                sub = cmd & 0x03
                if sub == 0:
                    tr.phase = "segments"                     # initiate confirmed
                elif sub == 2:
                    tr.acknowledge(d[1])
                    if tr.phase != "end":
                        tr.phase = "segments"
                elif sub == 1 and tr.phase == "last":
                    return [self._done(node_id, tr, t, tr.block_data())]
                return []
        else:
            if cs == 2:                                       # initiate upload response
                tr.mode = "expedited"
                if cmd & 0x02:
                    n = 4 - ((cmd >> 2) & 3) if cmd & 0x01 else 4
                    return [self._done(node_id, tr, t, bytes(d[4:4 + n]))]
                tr.mode = "segmented"
                tr.size = _U32.unpack_from(d, 4)[0] if cmd & 0x01 else None
                return []
            if tr.mode == "segmented" and cs == 0:            # upload segment
                n = (cmd >> 1) & 7
                tr.data += d[1:8 - n]
                tr.segments += 1
                return [self._done(node_id, tr, t, bytes(tr.data))] if cmd & 0x01 else []
            if tr.mode == "block" and cs == 6:                # ss is bit 0 only (CiA 301 7.2.4.3.14)
                if cmd & 0x01 == 0:                           # initiate response: size, then data
                    tr.size = _U32.unpack_from(d, 4)[0] if cmd & 0x02 else None
                    tr.phase = "segments"
                    return []
                if tr.phase == "end":                         # end: unused bytes, CRC
                    tr.unused = (cmd >> 2) & 7
                    tr.phase = "last"
                    return []
        return self._other(node_id, 0x580 + node_id, d, t)


class ControllerWatch:
    """What changed among the CAN controllers of a bus between two looks (sans-I/O): the rig's
    ``can-states`` answer for ``gatewaylab monitor``, the bus's controllers for the --web page.
    ``states`` maps a controller's name to ``state`` (error-active, error-passive, bus-off), ``tec``,
    ``rec``, ``connected`` and ``bus_offs`` (how often it went bus-off: a short bus-off with
    auto-recovery between two looks still shows). One ``can`` event per change."""

    def __init__(self) -> None:
        self.states: dict[str, Mapping[str, Any]] = {}
        self._first = True

    def update(self, states: Mapping[str, Mapping[str, Any]], now: float) -> list[MonitorEvent]:
        """Compare with the last look: one ``can`` event per controller whose state or counters changed."""
        events: list[MonitorEvent] = []

        def say(name: str, text: str, st: Mapping[str, Any]) -> None:
            events.append(MonitorEvent(now, "can", f"CAN {name}: {text}", None, {"controller": name, **st}))

        for name, st in states.items():
            old = self.states.get(name)
            counters = f"TEC {st.get('tec')}, REC {st.get('rec')}"
            if old is None:
                if not self._first:
                    say(name, "joined the bus", st)
                if st.get("state", "error-active") != "error-active":
                    say(name, f"{st.get('state')} ({counters})", st)
                if not st.get("connected", True):
                    say(name, "unplugged, off the bus", st)
                continue
            if old.get("connected") != st.get("connected"):
                say(name, "plugged in again" if st.get("connected") else "unplugged, left the bus", st)
            went = (st.get("bus_offs") or 0) - (old.get("bus_offs") or 0)
            times = f"{went} time{'s' * (went > 1)}"
            if old.get("state") != st.get("state"):
                how = " (recovered)" if old.get("state") == "bus-off" else ""
                if went > 0 and st.get("state") != "bus-off":
                    how = f" (went bus-off {times} in between)"
                say(name, f"{old.get('state')} -> {st.get('state')}{how} ({counters})", st)
            elif went > 0:
                say(name, f"went bus-off and recovered ({times}; now {st.get('state')}, {counters})", st)
        if not self._first:
            for name in self.states.keys() - states.keys():
                say(name, "left the bus (detached)", self.states[name])
        self.states = dict(states)
        self._first = False
        return events
