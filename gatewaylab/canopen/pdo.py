"""PDOs (CiA 301 7.2.2, 7.5.2.35-38; IDX guide 3.3.3.1): 4 RPDOs and 4 TPDOs.

Communication parameters 0x1400+n / 0x1800+n and mapping 0x1600+n / 0x1A00+n are writable by
the CiA 301 rules: a PDO is re-mapped only while it is not valid (COB-ID bit 31 set), mapping
entries only while sub-index 0 is 0, and sub-index 0 accepts only a count whose entries exist,
are mappable and fit in 8 bytes. Transmission types: 0 (acyclic synchronous), 1..240 (every
n-th SYNC), 252/253 (on remote request, sampled at SYNC / at the request), 254/255 (event: a
change of a mapped value or the event timer, limited by the inhibit time).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.communication import MAX_MAPPED, N_PDO
from gatewaylab.canopen.emcy import EMCY_PDO_LENGTH, EMCY_PDO_LENGTH_EXCEEDED, ERR_COMMUNICATION
from gatewaylab.canopen.errors import (
    GENERAL_PARAMETER_INCOMPATIBILITY,
    OBJECT_NOT_MAPPABLE,
    PDO_LENGTH_EXCEEDED,
    SUBINDEX_CANNOT_BE_WRITTEN,
    UNSUPPORTED_ACCESS,
    VALUE_RANGE_EXCEEDED,
    SdoAbort,
)
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import TimerHandle
from gatewaylab.od import DataType, Entry, KeyObject, decode, encode, type_size

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

AddHandler = Callable[[int, Callable[[CanFrame, float], None]], None]
Key = tuple[int, int]

COB_INVALID = 0x80000000
COB_NO_RTR = 0x40000000
COB_EXTENDED = 0x20000000


def restricted_cob_id(cob: int) -> bool:
    """COB-IDs CiA 301 table 22 reserves (NMT, SYNC/EMCY, TIME, SDO, LSS, NMT error control)."""
    return (cob == 0 or 0x001 <= cob <= 0x07F or 0x101 <= cob <= 0x180 or 0x581 <= cob <= 0x5FF
            or 0x601 <= cob <= 0x67F or 0x6E0 <= cob <= 0x6FF or 0x701 <= cob <= 0x77F
            or 0x780 <= cob <= 0x7FF)


class _Mapped:
    """One mapped object: its key (the entry's own key object, None = dummy), byte offset and size in the PDO."""

    __slots__ = ("entry", "key", "offset", "size")

    def __init__(self, entry: Entry | None, key: KeyObject | None, offset: int, size: int) -> None:
        self.entry = entry
        self.key = key
        self.offset = offset
        self.size = size


class _Pdo:
    def __init__(self, manager: PdoManager, number: int, comm: int, mapping: int) -> None:
        self.manager = manager
        self.node = manager.node
        #: the node's dictionary (compiled: a native object, where the node is reached through Python)
        self.od = manager.node.od
        self.number = number
        self.comm = comm
        self.mapping = mapping
        self.cob_id = 0
        self.valid = False
        self.rtr_allowed = True
        self.trans_type = 255
        self.mapped: list[_Mapped] = []
        self.length = 0
        self._whole: struct.Struct | None = None
        self._keys: tuple[KeyObject, ...] = ()
        self._entries: tuple[Entry, ...] = ()

    def configure(self) -> None:
        od = self.node.od
        cob = od.get(self.comm, 1)
        self.cob_id = cob & 0x7FF
        self.valid = not cob & COB_INVALID
        self.rtr_allowed = not cob & COB_NO_RTR
        self.trans_type = od.get(self.comm, 2)
        mapped: list[_Mapped] = []
        offset = 0
        for sub in range(1, od.get(self.mapping, 0) + 1):
            value = od.get(self.mapping, sub)
            index, s, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
            size = bits // 8
            entry = od.entries.get((index, s)) if index >= 0x1000 else None
            if entry is not None and entry.bit_length != bits:
                entry = None        # an inconsistent default/stored mapping acts like a dummy entry
                self.node.count("pdo_mapping_errors")
            mapped.append(_Mapped(entry, entry.key if entry is not None else None, offset, size))
            offset += size
        self.mapped = mapped
        self.length = offset
        # One struct for the whole PDO when every mapped object has a fixed-size codec (dummy
        # entries become pad bytes): a PDO is packed / unpacked in one call on the hot path.
        fmt = "<"
        keys: list[KeyObject] = []
        entries: list[Entry] = []
        for m in mapped:
            entry = m.entry
            if m.key is None or entry is None:
                fmt += f"{m.size}x"
            elif entry.codec is not None and not entry.limited:
                fmt += entry.codec.format[1:]
                keys.append(m.key)
                entries.append(entry)
            else:
                fmt = ""
                break
        whole = struct.Struct(fmt) if fmt and keys else None
        self._whole = whole if whole is not None and whole.size == offset else None
        self._keys = tuple(keys)
        self._entries = tuple(entries)


class Rpdo(_Pdo):
    """A receive PDO: frames on its COB-ID write the mapped objects (now or at the next SYNC)."""

    def __init__(self, manager: PdoManager, number: int) -> None:
        super().__init__(manager, number, 0x1400 + number, 0x1600 + number)
        self._pending: bytes | None = None
        self.received = 0
        #: the order in which apply() writes the entries (see configure)
        self._order: tuple[int, ...] = ()
        self._mapped_order: list[_Mapped] = []

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A received RPDO: written into the mapped objects now, or at the next SYNC when synchronous."""
        if frame.rtr or not self.valid or not self.mapped:
            return
        data = frame.data
        node = self.node
        emcy = node.emcy
        if len(data) < self.length:
            node.count("rpdo_length_errors")
            emcy.raise_error(EMCY_PDO_LENGTH, ERR_COMMUNICATION, bytes((self.number + 1, len(data))))
            return
        if len(data) > self.length:
            node.count("rpdo_length_errors")
            emcy.raise_error(EMCY_PDO_LENGTH_EXCEEDED, ERR_COMMUNICATION, bytes((self.number + 1, len(data))))
        elif emcy.active and (EMCY_PDO_LENGTH in emcy.active or EMCY_PDO_LENGTH_EXCEEDED in emcy.active):
            emcy.clear_error(EMCY_PDO_LENGTH)
            emcy.clear_error(EMCY_PDO_LENGTH_EXCEEDED)
        self.received += 1
        if self.trans_type <= 240:
            self._pending = data
        else:
            self.apply(data)

    def configure(self) -> None:
        """Read 0x1400+n / 0x1600+n again (COB-ID, transmission type, mapping) after a change."""
        super().configure()
        # Plain values (set-points) are written before the objects the device hooks (controlword,
        # mode), each group in mapping order: a controlword in the same PDO as its target (RPDO1 of
        # CiA 402: controlword + target position) acts on that target, as on a device that copies
        # the whole PDO into its dictionary before its application reads it. The hooks exist by
        # now (a device registers them before its node starts and configures its PDOs).
        hooked = self.node.od.intercepted
        entries = self._entries
        self._order = tuple(sorted(range(len(entries)), key=lambda i: entries[i].index in hooked))
        self._mapped_order = sorted(self.mapped, key=lambda m: m.entry is not None and m.entry.index in hooked)

    def apply(self, data: bytes) -> None:
        """Write the mapped objects: set-points first, then the hooked objects (see configure)."""
        node = self.node
        od = self.od
        whole = self._whole
        if whole is not None:   # unlimited fixed-size objects: decoding cannot fail
            values = whole.unpack_from(data)
            entries = self._entries
            for i in self._order:
                try:
                    od.store(entries[i], values[i])
                except SdoAbort:
                    node.count("rpdo_value_errors")
                except Exception:   # device hook misbehaved: count it, the bus carries on
                    node.count("hook_errors")
            return
        for m in self._mapped_order:
            entry = m.entry
            if entry is None:
                continue        # dummy mapping
            try:
                codec = entry.codec
                if codec is not None and not entry.limited:
                    value = codec.unpack_from(data, m.offset)[0]
                else:
                    value = decode(entry, data[m.offset:m.offset + m.size])
                od.store(entry, value)
            except SdoAbort:
                node.count("rpdo_value_errors")
            except Exception:   # device hook misbehaved: count it, the bus carries on
                node.count("hook_errors")


class Tpdo(_Pdo):
    """A transmit PDO: sent on SYNC, on remote request, on events or by its event timer."""

    def __init__(self, manager: PdoManager, number: int) -> None:
        super().__init__(manager, number, 0x1800 + number, 0x1A00 + number)
        self.inhibit = 0.0
        self.event_time = 0.0
        self.sync_start = 0
        self._sync_count = 0
        self._started = False
        self._pending_event = False
        self._sampled: bytes | None = None
        self._last_tx = -1e9
        self._inhibit_timer: TimerHandle | None = None
        self._event_timer: TimerHandle | None = None
        self.sent = 0

    def configure(self) -> None:
        """Read 0x1800+n / 0x1A00+n again (COB-ID, transmission type, inhibit time, event timer, mapping)."""
        super().configure()
        od = self.node.od
        # sub-indices 3, 5 and 6 are optional (CiA 301 7.5.2.37): a device without them has none
        entries = od.entries
        self.inhibit = (od.get(self.comm, 3) if (self.comm, 3) in entries else 0) * 100e-6
        self.event_time = (od.get(self.comm, 5) if (self.comm, 5) in entries else 0) / 1000.0
        self.sync_start = od.get(self.comm, 6) if (self.comm, 6) in entries else 0
        self._sync_count = 0
        self._started = False
        self._pending_event = False
        self._sampled = None

    def halt(self) -> None:
        """Cancel the inhibit and event timers (NMT leaves Operational, the PDO is reconfigured)."""
        for handle in (self._inhibit_timer, self._event_timer):
            if handle is not None:
                handle.cancel()
        self._inhibit_timer = self._event_timer = None

    def build(self) -> bytes:
        """Sample the mapped objects now."""
        values: dict[Any, Any] = self.od.values   # indexed by the entries' key objects
        whole = self._whole
        if whole is not None:
            return whole.pack(*[values[key] for key in self._keys])
        out = bytearray(self.length)
        for m in self.mapped:
            entry = m.entry
            if m.key is not None and entry is not None:
                codec = entry.codec
                if codec is not None:
                    codec.pack_into(out, m.offset, values[m.key])
                else:
                    out[m.offset:m.offset + m.size] = encode(entry, values[m.key])[:m.size]
        return bytes(out)

    def _active(self) -> bool:
        """Valid, mapped (an empty mapping is no PDO) and the node Operational."""
        return self.valid and bool(self.mapped) and self.node.nmt_state is NmtState.OPERATIONAL

    def transmit(self, data: bytes | None = None) -> None:
        """Send now (used for SYNC and RTR, which ignore the inhibit time)."""
        node = self.node
        node.send(CanFrame(self.cob_id, self.build() if data is None else data))
        self.sent += 1
        self._last_tx = node.clock.now()
        if self._event_timer is not None or self.event_time > 0:
            self._arm_event_timer()

    def _arm_event_timer(self) -> None:
        if self._event_timer is not None:
            self._event_timer.cancel()
            self._event_timer = None
        if self.event_time > 0 and self.trans_type >= 254 and self._active():
            self._event_timer = self.node.clock.call_later(self.event_time, self._event_timer_fired)

    def _event_timer_fired(self) -> None:
        self._event_timer = None
        self.trigger()

    def on_value_changed(self, key: Key, value: Any) -> None:
        """Dictionary listener: a mapped object changed (an event, CiA 301 7.2.2)."""
        self.trigger()

    def trigger(self) -> None:
        """An application event: type 254/255 sends (respecting the inhibit time), type 0 at the next SYNC."""
        if not self._active():
            return
        if self.trans_type == 0:
            self._pending_event = True
            return
        if self.trans_type < 254:
            return
        if self._inhibit_timer is not None:
            return      # a transmission is already waiting for the inhibit time to pass
        now = self.node.clock.now()
        due = self._last_tx + self.inhibit
        if self.inhibit and now < due:
            self._inhibit_timer = self.node.clock.call_at(due, self._inhibit_passed)
            return
        self.transmit()

    def _inhibit_passed(self) -> None:
        self._inhibit_timer = None
        if self._active():
            self.transmit()

    def on_sync(self, counter: int | None) -> None:
        """A SYNC: transmit when the transmission type's count of SYNCs is reached (CiA 301 7.2.2.2)."""
        if not self.mapped:
            return
        tt = self.trans_type
        if tt == 0:
            if self._pending_event:
                self._pending_event = False
                self.transmit()
            return
        if tt == 252:
            self._sampled = self.build()
            return
        if tt > 240:
            return
        if not self._started:
            if self.sync_start and counter is not None and counter != self.sync_start:
                return
            self._started = True
            self._sync_count = 0
        self._sync_count += 1
        if self._sync_count >= tt:
            self._sync_count = 0
            self.transmit()

    def on_rtr(self, frame: CanFrame, t: float) -> None:
        """A remote request for this TPDO: answer it when RTR is allowed (types 252/253 and on request)."""
        if not frame.rtr or not self.rtr_allowed or not self._active():
            return
        if self.trans_type == 252:
            self.transmit(self._sampled if self._sampled is not None else self.build())
        else:
            self.transmit()


class PdoManager:
    """The PDOs of a :class:`Node` and the CiA 301 rules for their parameters."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.rpdo = [Rpdo(self, n) for n in range(N_PDO)]
        self.tpdo = [Tpdo(self, n) for n in range(N_PDO)]
        #: Ends the subscriptions of the event-driven TPDOs to the objects they map.
        self._unsubscribe: list[Callable[[], None]] = []
        #: What a SYNC concerns, from the configuration: valid synchronous RPDOs (types 0..240,
        #: the only ones that hold received data for it) and valid mapped TPDOs that act on it
        #: (types 0..240 and 252); the other PDOs ignore every SYNC.
        self._sync_rpdos: list[Rpdo] = []
        self._sync_tpdos: list[Tpdo] = []
        for n in range(N_PDO):
            for comm, mapping, receive in ((0x1400 + n, 0x1600 + n, True), (0x1800 + n, 0x1A00 + n, False)):
                node.add_validator(comm, self._comm_validator(comm, receive))
                node.add_validator(mapping, self._mapping_validator(comm, mapping, receive))
                node.add_reaction(comm, lambda e, v: self.reconfigure())
                node.add_reaction(mapping, lambda e, v: self.reconfigure())

    # -- configuration ---------------------------------------------------------------------------
    def configure(self) -> None:
        """Configure every PDO from the dictionary and list the synchronous ones the SYNC handler serves."""
        for pdo in (*self.rpdo, *self.tpdo):
            pdo.configure()
        self._sync_rpdos = [rpdo for rpdo in self.rpdo if rpdo.valid and rpdo.trans_type <= 240]
        self._sync_tpdos = [tpdo for tpdo in self.tpdo if tpdo.valid and tpdo.mapped
                            and (tpdo.trans_type <= 240 or tpdo.trans_type == 252)]
        self._subscribe_events()

    def _subscribe_events(self) -> None:
        """Event-driven TPDOs (types 0, 254, 255) subscribe to the objects they map, so that a
        change of a mapped value triggers them (CiA 301 7.2.2); a remap subscribes anew."""
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        od = self.node.od
        self._unsubscribe = [od.subscribe(m.key, tpdo.on_value_changed)
                             for tpdo in self.tpdo if tpdo.valid and (tpdo.trans_type == 0 or tpdo.trans_type >= 254)
                             for m in tpdo.mapped if m.key is not None]

    def reconfigure(self) -> None:
        """A communication or mapping object changed: halt, configure, rebuild the node's receive dispatch."""
        self.halt()
        self.configure()
        self.node.rebuild_dispatch()
        if self.node.nmt_state is NmtState.OPERATIONAL:
            for tpdo in self.tpdo:
                tpdo._arm_event_timer()

    def halt(self) -> None:
        """Stop every TPDO timer and forget RPDOs waiting for the next SYNC."""
        for tpdo in self.tpdo:
            tpdo.halt()
        for rpdo in self.rpdo:
            rpdo._pending = None

    def register(self, add: AddHandler) -> None:
        """Hand the node's dispatch the COB-IDs the PDOs receive (valid RPDOs, TPDO remote requests)."""
        for rpdo in self.rpdo:
            if rpdo.valid:
                add(rpdo.cob_id, rpdo.on_frame)
        for tpdo in self.tpdo:
            if tpdo.valid and tpdo.rtr_allowed:
                add(tpdo.cob_id, tpdo.on_rtr)

    def nmt_changed(self, old: NmtState, new: NmtState) -> None:
        """PDOs run only in Operational: start counting SYNCs there, stop the timers elsewhere."""
        if new is NmtState.OPERATIONAL:
            for tpdo in self.tpdo:
                tpdo._sync_count = 0        # counting of SYNCs starts anew in Operational
                tpdo._started = False
                tpdo._pending_event = False
                tpdo._arm_event_timer()
        elif old is NmtState.OPERATIONAL:
            self.halt()

    # -- runtime ---------------------------------------------------------------------------------
    def apply_sync_rpdos(self) -> None:
        """SYNC, first step: the data synchronous RPDOs received since the previous SYNC (each
        RPDO holds what it received before this SYNC in ``_pending``, None if nothing)."""
        for rpdo in self._sync_rpdos:
            data = rpdo._pending
            if data is not None:
                rpdo._pending = None
                rpdo.apply(data)

    def on_sync(self, counter: int | None) -> None:
        """SYNC, last step: synchronous TPDOs sample and send, type 252 samples."""
        for tpdo in self._sync_tpdos:
            tpdo.on_sync(counter)

    # -- CiA 301 parameter rules -----------------------------------------------------------------
    def _comm_validator(self, comm: int, receive: bool) -> Callable[[Entry, Any], None]:
        def validate(entry: Entry, value: Any) -> None:
            od = self.node.od
            valid_now = not od.get(comm, 1) & COB_INVALID
            sub = entry.subindex
            if sub == 1:
                if value & COB_EXTENDED:
                    raise SdoAbort(VALUE_RANGE_EXCEEDED, "only 11-bit COB-IDs (IDX: standard frames only)")
                new_valid = not value & COB_INVALID
                if new_valid and restricted_cob_id(value & 0x7FF):
                    raise SdoAbort(VALUE_RANGE_EXCEEDED, f"COB-ID 0x{value & 0x7FF:03X} is reserved")
                if valid_now and new_valid and (value & 0x7FF) != (od.get(comm, 1) & 0x7FF):
                    raise SdoAbort(VALUE_RANGE_EXCEEDED, "set bit 31 before changing the COB-ID")
                if new_valid and not valid_now:
                    self._check_mapping(comm + 0x200, od.get(comm + 0x200, 0), receive)
            elif sub == 2:
                if (receive and 240 < value < 254) or (not receive and 240 < value < 252):
                    raise SdoAbort(VALUE_RANGE_EXCEEDED, f"transmission type {value} is reserved")
            elif sub in (3, 6) and valid_now:
                raise SdoAbort(UNSUPPORTED_ACCESS, "inhibit time / SYNC start value only while not valid")
        return validate

    def _mapping_validator(self, comm: int, mapping: int, receive: bool) -> Callable[[Entry, Any], None]:
        def validate(entry: Entry, value: Any) -> None:
            od = self.node.od
            if not od.get(comm, 1) & COB_INVALID:
                raise SdoAbort(UNSUPPORTED_ACCESS, "PDO is valid: set COB-ID bit 31 before re-mapping")
            if entry.subindex == 0:
                if value > MAX_MAPPED:
                    raise SdoAbort(VALUE_RANGE_EXCEEDED)
                self._check_mapping(mapping, value, receive)
                return
            if od.get(mapping, 0) != 0:
                raise SdoAbort(SUBINDEX_CANNOT_BE_WRITTEN, "write 0 to sub-index 0 first")
            if value:
                self._check_entry(value, receive)
        return validate

    def _check_mapping(self, mapping: int, count: int, receive: bool) -> None:
        od = self.node.od
        bits = 0
        for sub in range(1, count + 1):
            bits += self._check_entry(od.get(mapping, sub), receive)
        if bits > 64:
            raise SdoAbort(PDO_LENGTH_EXCEEDED, f"{bits} bits mapped")

    def _check_entry(self, value: int, receive: bool) -> int:
        """Bits of a mapping entry; SdoAbort when the object cannot be mapped that way."""
        index, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        if 0x0001 <= index <= 0x0007 and sub == 0 and receive:
            size = type_size(DataType(index))          # dummy mapping (CiA 301 7.4.7.1)
            if size is None or bits != 8 * size:
                raise SdoAbort(GENERAL_PARAMETER_INCOMPATIBILITY, "dummy entry length")
            return bits
        entry = self.node.od.entries.get((index, sub))
        if entry is None or not entry.pdo_mappable or entry.size is None:
            raise SdoAbort(OBJECT_NOT_MAPPABLE, f"0x{index:04X}:{sub:02X} cannot be mapped")
        if (receive and not entry.access.writable) or (not receive and not entry.access.readable):
            raise SdoAbort(OBJECT_NOT_MAPPABLE, f"0x{index:04X}:{sub:02X} has the wrong access for this PDO")
        if bits != entry.bit_length:
            raise SdoAbort(GENERAL_PARAMETER_INCOMPATIBILITY,
                           f"0x{index:04X}:{sub:02X} is {entry.bit_length} bits, not {bits}")
        return bits
