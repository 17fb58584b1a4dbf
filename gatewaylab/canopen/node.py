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

from ..bus.bus import Controller, VirtualBus
from ..bus.frame import CanFrame
from ..common.clock import Clock
from ..common.errors import ConfigError, LocalError
from .communication import add_communication_objects
from .emcy import Emcy
from .errors import READ_ONLY, WRITE_ONLY, WRONG_NMT_STATE, SdoAbort
from .heartbeat import Heartbeat
from .nmt import NMT_COB_ID, NMT_TRANSITIONS, NmtCommand, NmtState, decode_nmt, encode_heartbeat
from .od import Access, Entry, ObjectDictionary, coerce, decode, encode
from .pdo import PdoManager
from .sdo_server import SdoServer
from .storage import Storage
from .sync import Sync

FrameHandler = Callable[[CanFrame, float], None]
WriteHook = Callable[[int, int, Any], None]
ReadHook = Callable[[int, int], None]
Validator = Callable[[Entry, Any], None]
NmtHook = Callable[[NmtState, NmtState], None]

COMMUNICATION_AREA = range(0x1000, 0x2000)
ALL_PARAMETERS = range(0x1000, 0x10000)


def _chain(first: FrameHandler, second: FrameHandler) -> FrameHandler:
    def both(frame: CanFrame, t: float) -> None:
        first(frame, t)
        second(frame, t)
    return both


class Node:
    """A CANopen slave: NMT, SDO server, 4 RPDO + 4 TPDO, SYNC, EMCY, heartbeat, store/restore."""

    def __init__(self, clock: Clock, bus: VirtualBus, node_id: int | None, od: ObjectDictionary,
                 name: str = "", *, store_path: Path | None = None, sdo_timeout: float = 1.0) -> None:
        if node_id is not None and not 1 <= node_id <= 127:
            raise ConfigError(f"node-id {node_id} out of 1..127 (None = unconfigured)")
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
        self._write_hooks: dict[int, list[WriteHook]] = {}
        self._read_hooks: dict[int, list[ReadHook]] = {}
        self._nmt_hooks: list[NmtHook] = []
        self._reset_hooks: list[Callable[[bool], None]] = []
        self._validators: dict[int, list[Validator]] = {}
        self._reactions: dict[int, list[Validator]] = {}
        self._commands: dict[int, Validator] = {}
        #: Indexes with a command, validator, write hook or reaction (others are stored directly).
        self._intercepted: set[int] = set()
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
        self.storage = Storage(self, store_path)

    # -- identity --------------------------------------------------------------------------------
    @property
    def node_id(self) -> int | None:
        """1..127, or None while unconfigured (LSS node-id 0xFF)."""
        return self._node_id

    @node_id.setter
    def node_id(self, value: int | None) -> None:
        if value is not None and not 1 <= value <= 127:
            raise ConfigError(f"node-id {value} out of 1..127 (None = unconfigured)")
        self._node_id = value
        self.od.node_id = value

    def __repr__(self) -> str:
        return f"<Node {self.name} id={self._node_id} {self.nmt_state.name}>"

    # -- hooks -----------------------------------------------------------------------------------
    def on_write(self, index: int, callback: WriteHook) -> None:
        """``callback(index, sub, value)`` after an SDO/RPDO write to ``index`` was stored.

        Raising :class:`SdoAbort` there undoes the write and the SDO client gets that code.
        """
        self._write_hooks.setdefault(index, []).append(callback)
        self._intercepted.add(index)

    def on_read(self, index: int, callback: ReadHook) -> None:
        """``callback(index, sub)`` before an SDO read of ``index`` (refresh a value lazily)."""
        self._read_hooks.setdefault(index, []).append(callback)

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
        if callback in self._listeners:
            self._listeners.remove(callback)
        for can_id, listeners in list(self._id_listeners.items()):
            if callback in listeners:
                listeners.remove(callback)
                if not listeners:
                    del self._id_listeners[can_id]
        self._merge_dispatch()

    def add_validator(self, index: int, validator: Validator) -> None:
        """Internal: ``validator(entry, value)`` may refuse a remote write with SdoAbort."""
        self._validators.setdefault(index, []).append(validator)
        self._intercepted.add(index)

    def add_reaction(self, index: int, reaction: Validator) -> None:
        """Internal: ``reaction(entry, value)`` after a remote write was stored."""
        self._reactions.setdefault(index, []).append(reaction)
        self._intercepted.add(index)

    def add_command(self, index: int, command: Validator) -> None:
        """Internal: writes to ``index`` run ``command(entry, value)`` and store nothing."""
        self._commands[index] = command
        self._intercepted.add(index)

    def count(self, what: str) -> None:
        self.stats[what] = self.stats.get(what, 0) + 1

    # -- object access as an SDO client sees it ------------------------------------------------
    def check_writable(self, index: int, sub: int) -> Entry:
        entry = self.od.entry(index, sub)
        if not entry.access.writable:
            raise SdoAbort(READ_ONLY, f"0x{index:04X}:{sub:02X}")
        if entry.preop_only and self.nmt_state is NmtState.OPERATIONAL:
            raise SdoAbort(WRONG_NMT_STATE, f"0x{index:04X}:{sub:02X} only outside Operational")
        return entry

    def read(self, index: int, sub: int) -> bytes:
        """The value as an SDO upload returns it; SdoAbort on unknown or write-only objects."""
        entry = self.od.entries.get((index, sub)) or self.od.entry(index, sub)
        if entry.access is Access.WO:
            raise SdoAbort(WRITE_ONLY, f"0x{index:04X}:{sub:02X}")
        hooks = self._read_hooks.get(index)
        if hooks is not None:
            for hook in hooks:
                hook(index, sub)
        return encode(entry, self.od.values[(index, sub)])

    def write(self, index: int, sub: int, data: bytes) -> None:
        """Write as an SDO download does: access rights, length, limits, service rules."""
        entry = self.check_writable(index, sub)
        self.store(entry, decode(entry, bytes(data)))

    def store(self, entry: Entry, value: Any) -> None:
        """Internal: validators, store, reactions and hooks for a checked, decoded value."""
        index = entry.index
        if index not in self._intercepted:    # a plain value (e.g. a PDO-mapped set-point)
            self.od.put(index, entry.sub, value)
            return
        command = self._commands.get(index)
        if command is not None:
            command(entry, value)
            return
        validators = self._validators.get(index)
        if validators is not None:
            for validator in validators:
                validator(entry, value)
        key = (index, entry.sub)
        values = self.od.values
        old = values[key]
        values[key] = value
        hooks = self._write_hooks.get(index)
        if hooks is not None:
            try:
                for hook in hooks:
                    hook(index, entry.sub, value)
            except Exception:
                values[key] = old
                raise
        reactions = self._reactions.get(index)
        if reactions is not None:
            for reaction in reactions:
                reaction(entry, value)
        if old != value:
            values[key] = old     # stored early for the hooks: od.put stores it and notifies
            self.od.put(index, entry.sub, value)

    # -- typed local access for device code -----------------------------------------------------
    def get(self, index: int, sub: int = 0) -> Any:
        """The typed value (no access checks)."""
        return self.od.get(index, sub)

    def set(self, index: int, sub: int, value: Any) -> None:
        """Set a typed value (no access checks, no hooks); event-driven TPDOs see the change."""
        key = (index, sub)
        entry = self.od.entries.get(key) or self.od.entry(index, sub)
        self.od.put(index, sub, coerce(entry, value))

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
        return self.od.to_eds(dcf=dcf, node_id=self._node_id)

    @classmethod
    def from_eds(cls, clock: Clock, bus: VirtualBus, node_id: int | None, source: str | Path,
                 name: str = "", **kwargs: Any) -> Node:
        """A node whose dictionary is built from EDS/DCF text, or from the file at a Path."""
        text = source.read_text(encoding="latin-1") if isinstance(source, Path) else source
        return cls(clock, bus, node_id, ObjectDictionary.from_eds(text, node_id), name, **kwargs)
