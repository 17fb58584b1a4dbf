"""A CANopen slave (CiA 301) on one controller of a virtual bus, sans-I/O on the injected clock.

The :class:`Node` owns the object dictionary access rules and the frame dispatch; the services
live in their own modules (SDO server, PDO, SYNC, EMCY, heartbeat/guarding, store/restore) and
plug in through three internal tables: *validators* (may refuse a write with an abort code),
*reactions* (run after a value was stored) and *commands* (objects whose writes trigger an
action and are not stored, like 0x1010 'save').
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from gatewaylab.bus.bus import Controller, VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.communication import add_communication_objects
from gatewaylab.canopen.emcy import Emcy
from gatewaylab.canopen.heartbeat import Heartbeat
from gatewaylab.canopen.nmt import NMT_COB_ID, NMT_TRANSITIONS, NmtCommand, NmtState, decode_nmt, encode_heartbeat
from gatewaylab.canopen.pdo import PdoManager
from gatewaylab.canopen.sdo_server import SdoServer
from gatewaylab.canopen.storage import Storage
from gatewaylab.canopen.sync import Sync
from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError, LocalError
from gatewaylab.common.store import JsonFileStore, ParameterStore
from gatewaylab.od import (
    Access,
    Entry,
    ObjectDictionary,
    ReadHook,
    SdoAbort,
    SdoAbortCode,
    Validator,
    WriteHook,
    coerce,
)
from gatewaylab.od.eds import export_eds, import_eds

FrameHandler = Callable[[CanFrame, float], None]
NmtHook = Callable[[NmtState, NmtState], None]

COMMUNICATION_AREA = range(0x1000, 0x2000)
ALL_PARAMETERS = range(0x1000, 0x10000)


def _chain(first: FrameHandler, second: FrameHandler) -> FrameHandler:
    def both(frame: CanFrame, t: float) -> None:
        first(frame, t)
        second(frame, t)
    return both


class CanopenAccess:
    """CiA 301 SDO access rules: access type, and 'only outside Operational' entries (0x0F00FFC0)."""

    __slots__ = ("node",)

    def __init__(self, node: Node) -> None:
        self.node = node

    def check_read(self, entry: Entry) -> None:
        """Write-only entries answer 0x06010001."""
        if entry.access is Access.WO:
            raise SdoAbort(SdoAbortCode.WRITE_ONLY, f"0x{entry.index:04X}:{entry.subindex:02X}")

    def check_write(self, entry: Entry, data: bytes) -> None:
        """Read-only entries answer 0x06010002, preop-only ones 0x0F00FFC0 in Operational."""
        if not entry.access.writable:
            raise SdoAbort(SdoAbortCode.READ_ONLY, f"0x{entry.index:04X}:{entry.subindex:02X}")
        if entry.preop_only and self.node.nmt_state is NmtState.OPERATIONAL:
            raise SdoAbort(SdoAbortCode.WRONG_NMT_STATE,
                           f"0x{entry.index:04X}:{entry.subindex:02X} only outside Operational")


class Node:
    """A CANopen slave: NMT, SDO server, 4 RPDO + 4 TPDO, SYNC, EMCY, heartbeat, store/restore."""

    def __init__(self, clock: Clock, bus: VirtualBus, node_id: int | None, od: ObjectDictionary,
                 name: str = "", *, store_path: Path | None = None, sdo_timeout: float = 1.0,
                 store: ParameterStore | None = None) -> None:
        if node_id is not None and not 1 <= node_id <= 127:
            raise ConfigError(f"node-id {node_id} out of 1..127 (None = unconfigured)")
        if od.owner is not None:
            # Hooks (PDO rules, store/restore commands, device logic) now live in the dictionary.
            raise ConfigError(f"this dictionary already belongs to {od.owner}; give each node its own (od.copy())")
        od.owner = name or f"node {node_id}"
        od.node_id = node_id
        add_communication_objects(od)
        self.clock = clock
        self.bus = bus
        self.od = od
        self.name = name or (f"node{node_id}" if node_id is not None else "node-unconfigured")
        self._node_id = node_id
        od.node_id = node_id
        self.nmt_state = NmtState.INITIALISING
        self.running = False
        #: Counters of things that went wrong without crashing (bad PDOs, hook errors, tx errors).
        self.stats: dict[str, int] = {}
        self._handlers: dict[int, FrameHandler] = {}
        self._dispatch: dict[int, FrameHandler] = {}
        self._listeners: list[FrameHandler] = []
        self._id_listeners: dict[int, list[FrameHandler]] = {}
        self._nmt_hooks: list[NmtHook] = []
        self._reset_hooks: list[Callable[[bool], None]] = []
        #: CiA 301 access rules of SDO transfers in the present NMT state.
        self.access = CanopenAccess(self)
        #: Power-on values of the writable entries: what the dictionary held when the node was built
        #: (defaults, or a DCF's configured values); node-id dependent entries follow the node-id.
        self._power_on: dict[tuple[int, int], Any] = {
            key: od.values[key] for key, entry in od.entries.items()
            if (entry.access.writable or key == (0x1003, 0)) and not entry.nodeid_offset}
        self.controller: Controller = bus.attach(self.name, on_frame=self._on_frame)
        self.sdo = SdoServer(self, timeout=sdo_timeout)
        self.emcy = Emcy(self)
        self.heartbeat = Heartbeat(self)
        self.sync = Sync(self)
        self.pdo = PdoManager(self)
        #: Non-volatile memory of 0x1010/0x1011: ``store``, else a JSON file at ``store_path``, else memory.
        self.storage = Storage(self, store if store is not None else
                               JsonFileStore(store_path) if store_path is not None else None)

    # -- identity --------------------------------------------------------------------------------
    @property
    def node_id(self) -> int | None:
        """1..127, or None while unconfigured (LSS node-id 0xFF)."""
        return self._node_id

    @node_id.setter
    def node_id(self, value: int | None) -> None:
        """1..127, or None while unconfigured (LSS node-id 0xFF)."""
        if value is not None and not 1 <= value <= 127:
            raise ConfigError(f"node-id {value} out of 1..127 (None = unconfigured)")
        self._node_id = value
        self.od.node_id = value

    def __repr__(self) -> str:
        return f"<Node {self.name} id={self._node_id} {self.nmt_state.name}>"

    # -- hooks -----------------------------------------------------------------------------------
    def on_write(self, index: int | range, callback: WriteHook) -> None:
        """``callback(index, subindex, value)`` after an SDO/RPDO write to ``index`` was stored.

        Raising :class:`SdoAbort` there undoes the write and the SDO client gets that code.
        """
        self.od.on_write(index, callback)

    def on_read(self, index: int | range, callback: ReadHook) -> None:
        """``callback(index, subindex)`` before an SDO read of ``index`` (refresh a value lazily)."""
        self.od.on_read(index, callback)

    def on_nmt_change(self, callback: NmtHook) -> None:
        """``callback(old, new)`` on every NMT state change (the drive's statusword bit 9)."""
        self._nmt_hooks.append(callback)

    def on_reset(self, callback: Callable[[bool], None]) -> None:
        """``callback(reset_node)`` at the start of a reset node (True) / communication (False)."""
        self._reset_hooks.append(callback)

    def on_sync(self, callback: Callable[[int | None, float], None]) -> None:
        """``callback(counter, t)`` on every SYNC consumed (after sync RPDOs, before sync TPDOs)."""
        self.sync.listeners.append(callback)

    def add_frame_listener(self, callback: FrameHandler, can_id: int | None = None) -> None:
        """``callback(frame, t)`` for every frame this node's controller receives, in any state;
        with ``can_id`` only for standard frames with that identifier (cheaper on a busy bus)."""
        if can_id is None:
            self._listeners.append(callback)
        else:
            self._id_listeners.setdefault(can_id, []).append(callback)
        self._merge_dispatch()

    def remove_frame_listener(self, callback: FrameHandler) -> None:
        """Undo :meth:`add_frame_listener`."""
        if callback in self._listeners:
            self._listeners.remove(callback)
        for can_id, listeners in list(self._id_listeners.items()):
            if callback in listeners:
                listeners.remove(callback)
                if not listeners:
                    del self._id_listeners[can_id]
        self._merge_dispatch()

    def add_validator(self, index: int | range, validator: Validator) -> None:
        """Internal: ``validator(entry, value)`` may refuse a remote write with SdoAbort."""
        self.od.add_validator(index, validator)

    def add_reaction(self, index: int | range, reaction: Validator) -> None:
        """Internal: ``reaction(entry, value)`` after a remote write was stored."""
        self.od.add_reaction(index, reaction)

    def add_command(self, index: int | range, command: Validator) -> None:
        """Internal: writes to ``index`` run ``command(entry, value)`` and store nothing."""
        self.od.add_command(index, command)

    def count(self, what: str) -> None:
        """Count something that went wrong without crashing (``stats``)."""
        self.stats[what] = self.stats.get(what, 0) + 1

    # -- object access as an SDO client sees it ------------------------------------------------
    def check_writable(self, index: int, subindex: int) -> Entry:
        """The entry, if an SDO download may write it in the present NMT state (else SdoAbort)."""
        entry = self.od.entry(index, subindex)
        self.access.check_write(entry, b"")
        return entry

    def read(self, index: int, subindex: int) -> bytes:
        """The value as an SDO upload returns it; SdoAbort on unknown or write-only objects."""
        return self.od.read(index, subindex)    # CiA 301 reads need no state: the default rule (no WO)

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Write as an SDO download does: access rights, length, limits, service rules."""
        self.od.write(index, subindex, data, self.access)

    def store(self, entry: Entry, value: Any) -> None:
        """Internal: validators, store, reactions and hooks for a checked, decoded value."""
        self.od.store(entry, value)

    # -- typed local access for device code -----------------------------------------------------
    def get(self, index: int, subindex: int = 0) -> Any:
        """The typed value (no access checks)."""
        return self.od.get(index, subindex)

    def set(self, index: int, subindex: int, value: Any) -> None:
        """Set a typed value (no access checks, no hooks); event-driven TPDOs see the change."""
        self.od.put(index, subindex, value)

    # -- frames ------------------------------------------------------------------------------------
    def send(self, frame: CanFrame) -> None:
        """Queue a frame on this node's controller (counted and dropped when that is impossible)."""
        try:
            self.controller.send(frame)
        except LocalError:
            self.count("tx_errors")

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        # Called for every frame on the bus, by every node: keep it to one dict lookup.
        listeners = self._listeners
        if listeners:
            for listener in listeners:
                listener(frame, t)
        handler = self._dispatch.get(frame.can_id)
        if handler is not None and not frame.extended:
            handler(frame, t)

    def _merge_dispatch(self) -> None:
        """One table of id-filtered listeners (every state) and service handlers (by NMT state)."""
        merged = dict(self._handlers)
        for can_id, listeners in self._id_listeners.items():
            for listener in reversed(listeners):
                prev = merged.get(can_id)
                merged[can_id] = listener if prev is None else _chain(listener, prev)
        self._dispatch = merged
        # Without listeners for every frame the controller's acceptance filter is the table
        # itself: the bus calls the handler of a frame's COB-ID directly (no call into the node
        # for frames it does not consume; extended frames were never dispatched).
        self.controller.rx_table = None if self._listeners else merged

    def rebuild_dispatch(self) -> None:
        """Recompute which COB-IDs this node consumes in its present NMT state."""
        handlers: dict[int, FrameHandler] = {}

        def add(cob_id: int, handler: FrameHandler) -> None:
            prev = handlers.get(cob_id)
            handlers[cob_id] = handler if prev is None else _chain(prev, handler)

        state = self.nmt_state
        if self.running and self._node_id is not None and state is not NmtState.INITIALISING:
            add(NMT_COB_ID, self._on_nmt)
            self.heartbeat.register(add)
            if state is not NmtState.STOPPED:
                if self.sdo.rx_cob_id:
                    add(self.sdo.rx_cob_id, self.sdo.on_frame)
                self.sync.register(add)
            if state is NmtState.OPERATIONAL:
                self.pdo.register(add)
        self._handlers = handlers
        self._merge_dispatch()

    # -- NMT ---------------------------------------------------------------------------------------
    def _on_nmt(self, frame: CanFrame, t: float) -> None:
        msg = decode_nmt(frame)
        if msg is None or (msg.node_id != 0 and msg.node_id != self._node_id):
            return
        self.nmt_command(msg.command)

    def nmt_command(self, command: NmtCommand) -> None:
        """Apply an NMT command as if it had been received (IDX guide table 3-11)."""
        if command is NmtCommand.RESET_NODE:
            self.reset_node()
        elif command is NmtCommand.RESET_COMMUNICATION:
            self.reset_communication()
        else:
            new = NMT_TRANSITIONS.get((self.nmt_state, command))
            if new is not None:
                self._set_state(new)

    def _set_state(self, new: NmtState) -> None:
        old = self.nmt_state
        if new is old:
            return
        self.nmt_state = new
        if new is not NmtState.PRE_OPERATIONAL and new is not NmtState.OPERATIONAL:
            self.sdo.cancel()
        self.rebuild_dispatch()
        self.pdo.nmt_changed(old, new)
        self.sync.nmt_changed(new)
        for hook in list(self._nmt_hooks):
            hook(old, new)

    # -- life cycle ------------------------------------------------------------------------------
    def start(self) -> None:
        """Power on: stored parameters are loaded, boot-up is sent, the node is Pre-operational."""
        if self.running:
            return
        if self.controller not in self.bus.controllers:
            self.controller = self.bus.attach(self.name, on_frame=self._on_frame)
            self._merge_dispatch()
        self.running = True
        self._boot(reset_node=True)

    def stop(self) -> None:
        """Power off: timers cancelled, the controller leaves the bus."""
        if not self.running:
            return
        self._halt()
        self.running = False
        old, self.nmt_state = self.nmt_state, NmtState.INITIALISING
        self._handlers = {}
        self._merge_dispatch()
        self.controller.flush_tx()
        self.bus.detach(self.controller)
        if old is not NmtState.INITIALISING:
            for hook in list(self._nmt_hooks):
                hook(old, NmtState.INITIALISING)

    def reset_node(self) -> None:
        """NMT reset node: application and communication parameters back to their power-on values."""
        if self.running:
            self._boot(reset_node=True)

    def reset_communication(self) -> None:
        """NMT reset communication: communication parameters back to their power-on values."""
        if self.running:
            self._boot(reset_node=False)

    def _halt(self) -> None:
        self.sdo.cancel()
        self.pdo.halt()
        self.sync.halt()
        self.heartbeat.halt()
        self.emcy.halt()

    def _boot(self, reset_node: bool) -> None:
        old = self.nmt_state
        self._halt()
        self.nmt_state = NmtState.INITIALISING
        self._handlers = {}
        self._merge_dispatch()
        if old is not NmtState.INITIALISING:
            for hook in list(self._nmt_hooks):
                hook(old, NmtState.INITIALISING)
        for reset_hook in list(self._reset_hooks):
            reset_hook(reset_node)
        area = ALL_PARAMETERS if reset_node else COMMUNICATION_AREA
        self._reset_values(area)
        self.storage.apply(area)
        if reset_node:
            self.emcy.clear_all(send=False)
        node_id = self._node_id
        if node_id is None:
            self.rebuild_dispatch()
            return      # unconfigured: waits for LSS in Initialisation, no boot-up (CiA 305)
        self.sdo.configure()
        self.emcy.configure()
        self.sync.configure()
        self.pdo.configure()
        self.heartbeat.configure()
        self.send(encode_heartbeat(node_id, NmtState.INITIALISING))     # boot-up
        self._set_state(NmtState.PRE_OPERATIONAL)
        self.heartbeat.start()

    def _reset_values(self, area: range) -> None:
        """Writable entries of ``area`` back to their power-on values (read-only ones belong to the device)."""
        od = self.od
        node_id = self._node_id
        values = od.values
        power_on = self._power_on
        for key, entry in od.entries.items():
            if key[0] not in area:
                continue
            if entry.nodeid_offset:
                values[key] = coerce(entry, entry.default_for(node_id))
            elif key in power_on:
                values[key] = power_on[key]
            elif entry.access.writable:
                values[key] = coerce(entry, entry.default_for(node_id))

    def to_eds(self, *, dcf: bool = False) -> str:
        """EDS (or DCF) text of this node's dictionary."""
        return export_eds(self.od, dcf=dcf, node_id=self._node_id)

    @classmethod
    def from_eds(cls, clock: Clock, bus: VirtualBus, node_id: int | None, source: str | Path,
                 name: str = "", **kwargs: Any) -> Node:
        """A node whose dictionary is built from EDS/DCF text, or from the file at a Path."""
        text = source.read_text(encoding="latin-1") if isinstance(source, Path) else source
        return cls(clock, bus, node_id, import_eds(text, node_id), name, **kwargs)
