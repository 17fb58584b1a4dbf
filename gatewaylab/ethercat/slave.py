"""A complete emulated slave: ESC + SII + mailbox (CoE, FoE) + object dictionary + process image.

Devices (the ``ethercat_io`` test device, ECAN-Lite, esd CAN-EtherCAT) are a
:class:`DeviceDescription` plus a :class:`SlaveApplication` that refuses/acts on state
transitions, consumes outputs and produces inputs each cycle, serves FoE files, reacts to SYNC0
and binds object hooks (:meth:`SlaveApplication.setup_od`: read/write hooks, validators, apply
commands). The process image is backed by the dictionary, as SOES binds object rows to process
variables: outputs received in OP are stored into their mapped objects, a change of a mapped
input object (``od.put``) is packed into the inputs at once, and a CoE read of a mapped input
returns what the master reads.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Final, final

from mypy_extensions import mypyc_attr

from gatewaylab.common.clock import Clock
from gatewaylab.ethercat.coe import CoeServer, emergency_message
from gatewaylab.ethercat.description import DeviceDescription, Pdo, build_od
from gatewaylab.ethercat.errors import AlStatusCode, EtherCATConfigError, MailboxErrorCode
from gatewaylab.ethercat.esc import RAM_START, REG_AL_STATUS, REG_SM, SM_STATUS_FULL, AlState, Esc
from gatewaylab.ethercat.esc_events import AlControlRequested, EscEvent, SmRead, SmWritten
from gatewaylab.ethercat.foe import FoeFiles, FoeHandler, FoeServer
from gatewaylab.ethercat.mailbox import MailboxEndpoint, MailboxMessage, MailboxType, error_reply
from gatewaylab.ethercat.sii import build_sii
from gatewaylab.ethercat.slave_faults import MailboxFaults
from gatewaylab.od import DataType, Entry, ObjectDictionary, SdoAbort, decode, encode

__all__ = ["MappedEntry", "Slave", "SlaveApplication", "build_od"]

U32: Final = struct.Struct("<I")
_RANK_ORDER = (AlState.INIT, AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP)


@mypyc_attr(allow_interpreted_subclasses=True)  # devices subclass it; the ESC path is compiled
class SlaveApplication:
    """Hooks of a device behind the ESC; every method has a harmless default."""

    #: False: outputs received in OP are not stored into their mapped objects every cycle (a
    #: device that parses the raw outputs in :meth:`on_outputs`, e.g. large message queues);
    #: a CoE read of a mapped output then decodes it from the outputs image instead.
    store_outputs: ClassVar[bool] = True

    #: (Both are ``ClassVar``: compiled, a plain attribute is a slot of the native base class that the
    #: ``store_outputs = False`` of an interpreted subclass does not reach; the native code read True.)
    #:
    #: True: outputs reach the application on the SM2 write event, inside the frame, before the same
    #: datagram reads the inputs (``ethercat_io``'s loop-back answers in the same LRW). False: the
    #: ESC takes the buffer in the frame and the application gets it once the frame has passed
    #: (:meth:`Slave.after_frame`): a real ESC answers a frame as it passes while the firmware reads
    #: and writes process RAM between frames (ET1100 data sheet: the SM2 buffer event interrupts the
    #: PDI), so the application's work (a drive's controlword and set-points) is not part of the round
    #: trip; its answer is in the inputs of the next frame.
    outputs_in_frame: ClassVar[bool] = True

    #: True: :meth:`on_inputs_read` runs inside the frame, as the master's read of the inputs buffer
    #: passes (``ethercat_io`` and the ESI rules refresh their inputs there). False: the ESC hands the
    #: buffer over in the frame and the application hears of the read once the frame has passed
    #: (:meth:`Slave.after_frame`), as a firmware does on the SM3 interrupt: a device that builds its
    #: next inputs image from queues (the ECAN-Lite's TxPDO stream) does that work between frames, and
    #: the next frame reads the image it staged.
    inputs_read_in_frame: ClassVar[bool] = True

    def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
        """Bind the device's object hooks once the dictionary exists: ``od.on_read`` (status
        objects, counters), ``od.on_write`` / ``od.add_reaction`` ("apply" commands),
        ``od.add_validator`` (refuse values with an SDO abort), per index or per index range."""

    def on_transition(self, slave: Slave, old: AlState, new: AlState) -> int:
        """Return 0 to accept, or an AL status code to refuse the transition."""
        return 0

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        """The state changed (``code`` != 0 when the slave fell back by itself, e.g. 0x001B)."""

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        """New outputs arrived in OP: called from the frame path (keep it short), or once the frame has
        passed when ``outputs_in_frame`` is False."""

    def on_inputs_read(self, slave: Slave) -> None:
        """The master read the whole inputs buffer; refresh inputs for the next cycle here."""

    def on_sync0(self, slave: Slave, t: float) -> None:
        """A SYNC0 pulse (DC) at clock time ``t``."""


@dataclass(frozen=True, slots=True)
class MappedEntry:
    """An object mapped in the process image at a bit offset."""

    index: int
    subindex: int
    bit_offset: int
    bit_length: int
    data_type: DataType

    @property
    def key(self) -> tuple[int, int]:
        """(index, subindex) of the mapped object."""
        return (self.index, self.subindex)


@final
class _Slot:
    """A byte-aligned mapped object of fixed size whose raw bytes its entry's struct reads and writes:
    the process image's fast path (decoded once per layout, not per cycle)."""

    __slots__ = ("codec", "entry", "index", "key", "offset", "ram", "subindex")

    def __init__(self, m: MappedEntry, entry: Entry, codec: struct.Struct) -> None:
        self.key = m.key
        self.index = m.index
        self.subindex = m.subindex
        self.entry = entry
        self.codec = codec
        self.offset = m.bit_offset // 8
        #: an input's address in ESC memory when it lies inside process RAM, else -1 (set by the slave)
        self.ram = -1


def _slot(m: MappedEntry, entry: Entry | None) -> _Slot | None:
    """The fast-path slot of a mapped object, or None where the general path must serve it (bit-wise
    mapping, a mapping length other than the type's, variable size, limits to check)."""
    if entry is None or entry.codec is None or entry.limited or m.bit_offset % 8:
        return None
    codec = entry.codec
    if 8 * codec.size != m.bit_length:
        return None
    return _Slot(m, entry, codec)


def _desc_entries(pdos: tuple[Pdo, ...]) -> list[MappedEntry]:
    out: list[MappedEntry] = []
    bit = 0
    for pdo in pdos:
        for e in pdo.entries:
            if e.index:
                out.append(MappedEntry(e.index, e.subindex, bit, e.bit_length, e.data_type))
            bit += e.bit_length
    return out


class Slave:
    """One slave in a segment: feed it datagrams through :meth:`process_datagram`."""

    def __init__(self, clock: Clock, desc: DeviceDescription, app: SlaveApplication | None = None,
                 foe: FoeHandler | None = None, *, name: str | None = None, alias: int = 0,
                 od: ObjectDictionary | None = None) -> None:
        """``od``: the slave's own dictionary when the caller made it as ``build_od(desc)`` would (a copy of
        one built for many slaves of a type); None builds it from ``desc``."""
        self.clock = clock
        self.desc = desc
        self.name = name or desc.name
        self.app = app or SlaveApplication()
        self.od = od if od is not None else build_od(desc)
        self.sii = build_sii(desc, alias)
        #: Process data SyncManagers: 2/3 behind the mailbox SMs, 0/1 on a slave without mailbox.
        self.has_mailbox = desc.has_mailbox
        self.sm_outputs, self.sm_inputs = desc.sm_numbers
        self.esc = Esc(clock, self.sii, self, dc=desc.dc, output_sm=self.sm_outputs)
        self.mailbox = MailboxEndpoint(lambda raw: self.esc.mailbox_put(1, raw))
        mbx_size = desc.mailbox_in[1]
        self.coe = CoeServer(self.od, mbx_size, lambda: self.esc.al_state)
        self.foe_handler: FoeHandler = foe or FoeFiles()
        self.foe = FoeServer(self.foe_handler, mbx_size)
        #: mailbox faults armed on this slave (None: none, the usual case)
        self.mailbox_faults: MailboxFaults | None = None
        if desc.coe:
            self.mailbox.handlers[MailboxType.COE] = self._coe
        if desc.foe:
            self.mailbox.handlers[MailboxType.FOE] = self._foe
        self.outputs_map: list[MappedEntry] = _desc_entries(desc.assigned_rx_pdos)
        self.inputs_map: list[MappedEntry] = _desc_entries(desc.assigned_tx_pdos)
        self.output_bytes = desc.output_bytes
        self.input_bytes = desc.input_bytes
        self._inputs = bytearray(self.input_bytes)
        self._outputs = bytes(self.output_bytes)
        self.outputs_valid = False
        #: Outputs taken in the frame whose delivery to the application waits for :meth:`after_frame`
        #: (``SlaveApplication.outputs_in_frame`` False).
        self.outputs_pending = False
        #: The master read the inputs buffer in the frame; the application hears of it in
        #: :meth:`after_frame` (``SlaveApplication.inputs_read_in_frame`` False).
        self.inputs_read_pending = False
        self._inputs_one_buffer = False
        self.cycles = 0
        self._unbind: list[Callable[[], None]] = []
        self._input_by_key: dict[tuple[int, int], MappedEntry] = {}
        self._output_by_key: dict[tuple[int, int], MappedEntry] = {}
        #: fast paths of the image (see ``_Slot``): mapped inputs by key, outputs in mapping order
        #: (None: some output needs the general path)
        self._input_slots: dict[tuple[int, int], _Slot] = {}
        self._output_slots: list[_Slot] | None = None
        self._bind_image()
        for obj in self.od:
            if any(e.tx_pdo or e.rx_pdo for e in obj.entries.values()):
                self.od.on_read(obj.index, self._refresh_mapped)
        self.app.setup_od(self, self.od)

    # ------------------------------------------------------------------ datagrams and PDI events
    def process_datagram(self, buf: bytearray, pos: int, cmd: int, dlen: int) -> None:
        """Run one datagram of a frame through the ESC, delivering the PDI events of each access
        before the next access runs (the contract in :mod:`gatewaylab.ethercat.esc`)."""
        events = self.esc.process_datagram(buf, pos, cmd, dlen)
        if events is not None:
            self.serve_events(events)

    def serve_events(self, events: list[EscEvent]) -> None:
        """Deliver the PDI events of a paused datagram to the firmware, in order, and resume it, until
        it is complete: mailbox and process data SyncManagers, the AL state machine, the SM-change
        check (SOES's ESC_ALevent / ESC_sm_act_event)."""
        esc = self.esc
        pending: list[EscEvent] | None = events
        while pending is not None:
            for ev in pending:
                if isinstance(ev, SmWritten):
                    self.sm_written(ev.sm, esc.memory.pdi_outputs[ev.sm])
                elif isinstance(ev, SmRead):
                    self.sm_read(ev.sm)
                elif isinstance(ev, AlControlRequested):
                    esc.al_control(ev.control)
                else:
                    self.sm_changed()
            pending = esc.resume_datagram()

    # ------------------------------------------------------------------ the firmware (EscApplication)
    def check_transition(self, old: AlState, new: AlState) -> int:
        """AL state machine: 0 to accept an AL state transition, else the AL status code."""
        d = self.desc
        if new == AlState.BOOT:
            if not d.bootstrap:
                return AlStatusCode.BOOTSTRAP_NOT_SUPPORTED
            bo, bos, bi, bis = d.bootstrap_mailbox
            if not self._sm_ok(0, bo, bos, 0x06) or not self._sm_ok(1, bi, bis, 0x02):
                return AlStatusCode.INVALID_MAILBOX_CONFIG_BOOT
        if old == AlState.INIT and new == AlState.PREOP and d.has_mailbox and (
                not self._sm_ok(0, *d.mailbox_out, 0x06) or not self._sm_ok(1, *d.mailbox_in, 0x02)):
            return AlStatusCode.INVALID_MAILBOX_CONFIG
        if old == AlState.PREOP and new == AlState.SAFEOP:
            code = self._compute_layout()
            if code:
                return code
            if not self._sms_disjoint():
                return AlStatusCode.INVALID_SM_CONFIG
            if not self._pd_sm_ok(self.sm_outputs, d.outputs_start, self.output_bytes, d.outputs_control & 0x0F):
                return AlStatusCode.INVALID_OUTPUT_CONFIG
            if not self._pd_sm_ok(self.sm_inputs, d.inputs_start, self.input_bytes, d.inputs_control & 0x0F):
                return AlStatusCode.INVALID_INPUT_CONFIG
        return self.app.on_transition(self, old, new)

    def _sm_ok(self, index: int, start: int, length: int, mode: int) -> bool:
        sm = self.esc.sm_config(index)
        return sm.enabled and sm.start == start and sm.length == length and (sm.control & 0x0F) == mode

    def _sms_disjoint(self) -> bool:
        """Enabled SyncManagers must lie in the process RAM, or be an output SyncManager on the Digital I/O
        Output Data register 0x0F00:0x0F03 (an EL2008's), and must not overlap."""
        ranges = []
        for i in range(self.esc.n_sm):
            sm = self.esc.sm_config(i)
            if self.esc.sm_in_use(i):
                if (sm.start < RAM_START and not sm.on_output_register) or sm.start + sm.length > len(self.esc.mem):
                    return False
                ranges.append((sm.start, sm.start + sm.length))
        ranges.sort()
        return all(a[1] <= b[0] for a, b in itertools.pairwise(ranges))

    def _pd_sm_ok(self, index: int, start: int, length: int, mode: int) -> bool:
        """Start, length and direction as the SII says. The buffer type may differ from the SII's (KickCAT
        programs 3-buffer process data SyncManagers whatever the SII says) when the buffers then still
        fit: three times the length inside the process RAM, clear of every other SyncManager
        (docs/decisions.md: KickCAT interop)."""
        sm = self.esc.sm_config(index)
        if length == 0:
            return not sm.enabled
        if not (sm.enabled and sm.start == start and sm.length == length and (sm.control & 0x0C) == mode & 0x0C):
            return False
        if (sm.control & 0x03) == mode & 0x03:
            return True
        end = start + length * (1 if sm.mailbox else 3)
        if end > len(self.esc.mem):
            return False
        for i in range(self.esc.n_sm):
            other = self.esc.sm_config(i)
            if i != index and self.esc.sm_in_use(i) and other.start < end and start < other.start + other.length:
                return False
        return True

    def state_changed(self, old: AlState, new: AlState, code: int) -> None:
        """AL state machine, after a state change: mailbox reset, safe outputs, application."""
        if new in (AlState.INIT, AlState.BOOT):
            self.mailbox.reset()
            size = self.desc.bootstrap_mailbox[3] if new == AlState.BOOT else self.desc.mailbox_in[1]
            self.foe = FoeServer(self.foe_handler, size)
            self.coe = CoeServer(self.od, self.desc.mailbox_in[1], lambda: self.esc.al_state)
        if new in (AlState.SAFEOP, AlState.OP) and old in (AlState.PREOP, AlState.INIT):
            self._inputs_one_buffer = self.esc.sm_config(self.sm_inputs).mailbox
            self.write_inputs(bytes(self._inputs))
        elif new in (AlState.INIT, AlState.PREOP, AlState.BOOT):
            self._inputs_one_buffer = False
        if new != AlState.OP and old == AlState.OP:
            self._outputs = bytes(self.output_bytes)  # safe state
            self.outputs_valid = False
            self.outputs_pending = False
            self._store_outputs()
        if new not in (AlState.SAFEOP, AlState.OP):
            self.inputs_read_pending = False
        self.app.on_state(self, old, new, code)

    def sm_written(self, sm: int, data: bytes) -> None:
        """PDI event: the master wrote a SyncManager buffer (mailbox or outputs)."""
        if sm == 0 and self.has_mailbox:
            self.mailbox_received(data)
        elif sm == self.sm_outputs:
            self.outputs_written(sm, data)

    def sm_changed(self) -> None:
        """PDI event: the master wrote SyncManager registers (the SM-change event, ET1100 AL event
        0x0220 bit 4). As SOES's ``ESC_sm_act_event`` does, a running mailbox whose SyncManagers no
        longer match the SII (moved, resized, disabled, or not activated by the ESC because the master
        put them over the registers) stops: INIT + error, AL status code 0x0016 invalid mailbox
        configuration; in SAFEOP/OP a process data SyncManager that no longer fits drops the slave to
        PREOP + error with 0x001D / 0x001E. A master's normal re-initialisation (INIT with
        acknowledge, SyncManagers programmed again) clears both."""
        state = self.esc.al_state
        if state in (AlState.INIT, AlState.BOOT):
            return
        d = self.desc
        if self.has_mailbox and not (self._sm_ok(0, *d.mailbox_out, 0x06) and self._sm_ok(1, *d.mailbox_in, 0x02)
                                     and self.esc.sm_active(0) and self.esc.sm_active(1)):
            self.esc.force_state(AlState.INIT, AlStatusCode.INVALID_MAILBOX_CONFIG)
            return
        if state not in (AlState.SAFEOP, AlState.OP):
            return
        if not self._pd_sm_runs(self.sm_outputs, d.outputs_start, self.output_bytes, d.outputs_control):
            self.esc.force_state(AlState.PREOP, AlStatusCode.INVALID_OUTPUT_CONFIG)
        elif not self._pd_sm_runs(self.sm_inputs, d.inputs_start, self.input_bytes, d.inputs_control):
            self.esc.force_state(AlState.PREOP, AlStatusCode.INVALID_INPUT_CONFIG)

    def _pd_sm_runs(self, index: int, start: int, length: int, control: int) -> bool:
        """A process data SyncManager as PREOP->SAFEOP accepted it, and running in the ESC (or the output
        SyncManager the firmware itself deactivated on leaving OP)."""
        esc = self.esc
        return self._pd_sm_ok(index, start, length, control & 0x0F) and (
            length == 0 or esc.sm_active(index) or (index == self.sm_outputs and esc.outputs_stopped))

    def sm_read(self, sm: int) -> None:
        """PDI event: the master read a SyncManager buffer (mailbox or inputs)."""
        if sm == 1 and self.has_mailbox:
            faults = self.mailbox_faults
            if faults is not None and faults.take_lost_reply():
                self.esc.lose_datagram()        # the master must repeat (SM1 repeat request, 0x0806)
            self.mailbox.pump()
        elif sm == self.sm_inputs:
            app = self.app
            if app.inputs_read_in_frame:
                app.on_inputs_read(self)
            else:
                self.inputs_read_pending = True     # told by after_frame, once the frame has passed
            if self._inputs_one_buffer:
                self.esc.sm_set_full(sm)  # 1-buffer inputs: the application refreshes every cycle

    def mailbox_received(self, data: bytes) -> None:
        """A complete mailbox write from the master (discarded in INIT)."""
        self.esc.mailbox_clear(0)  # the PDI read the buffer
        state = self.esc.al_state
        if state == AlState.INIT:
            return
        if state == AlState.BOOT and (len(data) < 6 or data[5] & 0x0F != MailboxType.FOE):
            self.mailbox.send(error_reply(MailboxErrorCode.UNSUPPORTED_PROTOCOL))  # BOOT: only FoE (IDX 4.2)
            return
        self.mailbox.received(data)

    def outputs_written(self, sm: int, data: bytes) -> None:
        """A complete outputs buffer: stored into the mapped objects, then the application."""
        esc = self.esc
        if esc.mem[REG_SM + 8 * sm + 5] & SM_STATUS_FULL:
            esc.mailbox_clear(sm)  # 1-buffer outputs: the PDI consumed them
        self.cycles += 1
        if esc.mem[REG_AL_STATUS] & 0x0F == AlState.OP:  # hot path: no enum construction
            self._outputs = data if len(data) == self.output_bytes else data[:self.output_bytes]
            self.outputs_valid = True
            app = self.app
            if not app.outputs_in_frame:
                self.outputs_pending = True     # delivered by after_frame, once the frame has passed
                return
            if app.store_outputs:
                self._store_outputs()
            app.on_outputs(self, self._outputs)

    def after_frame(self) -> None:
        """The PDI's work between frames: outputs taken in the last frames reach the application (an
        application with ``outputs_in_frame`` False), then the application hears that the master read its
        inputs (``inputs_read_in_frame`` False); nothing when neither is pending. The outputs are dropped
        when the slave left OP meanwhile (its safe state is already applied), the read when it left
        SAFEOP and OP."""
        app = self.app
        if self.outputs_pending:
            self.outputs_pending = False
            if self.esc.mem[REG_AL_STATUS] & 0x0F == AlState.OP and self.outputs_valid:
                if app.store_outputs:
                    self._store_outputs()
                app.on_outputs(self, self._outputs)
        if self.inputs_read_pending:
            self.inputs_read_pending = False
            app.on_inputs_read(self)

    def sync0(self, t: float) -> None:
        """The ESC's SYNC0 line (a clock timer, not an access): the application's SYNC0 hook."""
        self.app.on_sync0(self, t)

    # ------------------------------------------------------------------ mailbox protocols
    def _coe(self, data: bytes) -> list[bytes]:
        faults = self.mailbox_faults
        if faults is not None:
            replies = faults.coe(data, self.coe)
            if replies is not None:
                return replies
        return self.coe.handle(data)

    def _foe(self, data: bytes) -> list[bytes]:
        faults = self.mailbox_faults
        if faults is not None:
            return faults.foe(data, self.foe)
        return self.foe.handle(data)

    def emergency(self, error_code: int, error_register: int = 0, data: bytes = b"") -> None:
        """Send a CoE emergency message through the mailbox (ETG.1000.6 CoE emergency)."""
        self.mailbox.send(MailboxMessage(MailboxType.COE, emergency_message(error_code, error_register, data)))

    def fault(self, code: int, state: AlState = AlState.SAFEOP) -> None:
        """The device falls back by itself (e.g. CAN bus-off): ``state`` + error flag + AL status code;
        the master must acknowledge (AL control bit 4) before it can go up again."""
        current = self.esc.al_state
        target = state if _RANK_ORDER.index(state) < _RANK_ORDER.index(current) else current
        self.esc.force_state(target, code)

    # ------------------------------------------------------------------ process data
    @property
    def state(self) -> AlState:
        """The present AL state."""
        return self.esc.al_state

    @property
    def outputs(self) -> bytes:
        """Outputs the device acts on: the master's in OP, the safe state (zeros) otherwise."""
        return self._outputs

    @property
    def inputs(self) -> bytes:
        """The inputs image the master reads."""
        return bytes(self._inputs)

    def write_inputs(self, data: bytes, offset: int = 0) -> None:
        """Raw bytes into the inputs image at ``offset`` (CoE reads decode them from there)."""
        self._inputs[offset:offset + len(data)] = data
        self.esc.pdi_write(self.desc.inputs_start + offset, data)
        if self._inputs_one_buffer:
            self.esc.sm_set_full(self.sm_inputs)

    def read_output(self, index: int, subindex: int) -> Any:
        """The typed value of a mapped output as the device acts on it."""
        m = self._find(self.outputs_map, index, subindex)
        return decode(self._entry(m), _get_bits(self._outputs, m.bit_offset, m.bit_length))

    def write_input(self, index: int, subindex: int, value: Any) -> None:
        """Set a mapped input: stored in its object and packed into the inputs at once."""
        m = self._find(self.inputs_map, index, subindex)
        if m.key not in self.od.entries or not self.od.put(index, subindex, value):
            self._pack_input(m, self._entry(m), value)

    # ------------------------------------------------------------------ dictionary-backed image
    def _entry(self, m: MappedEntry) -> Entry:
        entry = self.od.entries.get(m.key)
        return entry if entry is not None else Entry(m.index, m.subindex, "", m.data_type)

    def _pack_input(self, m: MappedEntry, entry: Entry, value: Any) -> None:
        raw = encode(entry, value)
        if m.bit_length % 8 == 0 and m.bit_offset % 8 == 0:
            self.write_inputs(raw[:m.bit_length // 8].ljust(m.bit_length // 8, b"\0"), m.bit_offset // 8)
        else:
            _set_bits(self._inputs, m.bit_offset, m.bit_length, raw)
            self.esc.pdi_write(self.desc.inputs_start, bytes(self._inputs))
            if self._inputs_one_buffer:
                self.esc.sm_set_full(self.sm_inputs)

    def _input_changed(self, key: tuple[int, int], value: Any) -> None:
        slot = self._input_slots.get(key)
        if slot is None:
            m = self._input_by_key[key]
            self._pack_input(m, self.od.entries[key], value)
            return
        # the fast path of _pack_input: the value packed into the image and into process RAM
        inputs = self._inputs
        offset = slot.offset
        codec = slot.codec
        if offset + codec.size > len(inputs):
            self._pack_input(self._input_by_key[key], slot.entry, value)
            return
        codec.pack_into(inputs, offset, value)
        if slot.ram >= 0:
            codec.pack_into(self.esc.mem, slot.ram, value)      # pdi_write without the copies
        else:
            self.esc.pdi_write(self.desc.inputs_start + offset, inputs[offset:offset + codec.size])
        if self._inputs_one_buffer:
            self.esc.sm_set_full(self.sm_inputs)

    def _bind_image(self) -> None:
        """Subscribe to the mapped input objects (after every layout change)."""
        for unsubscribe in self._unbind:
            unsubscribe()
        self._input_by_key = {m.key: m for m in self.inputs_map}
        self._output_by_key = {m.key: m for m in self.outputs_map}
        entries = self.od.entries
        self._input_slots = {}
        ram_end = len(self.esc.mem)
        for m in self.inputs_map:
            slot = _slot(m, entries.get(m.key))
            if slot is not None:
                address = self.desc.inputs_start + slot.offset
                if address >= RAM_START and address + slot.codec.size <= ram_end:
                    slot.ram = address
                self._input_slots[m.key] = slot
        outputs: list[_Slot] = []
        for m in self.outputs_map:
            slot = _slot(m, entries.get(m.key))
            if slot is None:
                break
            outputs.append(slot)
        self._output_slots = outputs if len(outputs) == len(self.outputs_map) else None
        self._unbind = [self.od.subscribe(key, self._input_changed)
                        for key in self._input_by_key if key in self.od.entries]

    def _store_outputs(self) -> None:
        """The outputs the device acts on, into their mapped objects."""
        od = self.od
        data = self._outputs
        slots = self._output_slots
        if slots is not None:
            # fast path (every output a byte-aligned fixed-size object without limits): only the
            # values that differ from the stored ones are put (put stores nothing else either)
            values = od.values
            size = len(data)
            for slot in slots:
                codec = slot.codec
                if slot.offset + codec.size > size:
                    continue
                value = codec.unpack_from(data, slot.offset)[0]
                if values[slot.key] != value:
                    od.put(slot.index, slot.subindex, value)
            return
        for m in self.outputs_map:
            entry = od.entries.get(m.key)
            if entry is not None and m.bit_offset + m.bit_length <= 8 * len(data):
                try:
                    od.put(m.index, m.subindex, decode(entry, _get_bits(data, m.bit_offset, m.bit_length)))
                except SdoAbort:
                    pass  # a value the object cannot hold (e.g. a BOOLEAN of 2): keep the last one

    def _refresh_mapped(self, index: int, subindex: int) -> None:
        """Read hook of mapped objects: an input written as raw bytes (``write_inputs``) is
        decoded from the image, so a CoE read returns what the master reads; so is an output in
        OP when the application does not store outputs (``SlaveApplication.store_outputs``)."""
        image: bytes | bytearray = self._inputs
        m = self._input_by_key.get((index, subindex))
        if m is None and not self.app.store_outputs and self.outputs_valid:
            m = self._output_by_key.get((index, subindex))
            image = self._outputs
        if m is None or m.bit_offset + m.bit_length > 8 * len(image):
            return
        entry = self.od.entries[m.key]
        try:
            self.od.values[m.key] = decode(entry, _get_bits(image, m.bit_offset, m.bit_length))
        except SdoAbort:
            pass

    @staticmethod
    def _find(mapping: list[MappedEntry], index: int, subindex: int) -> MappedEntry:
        for m in mapping:
            if m.index == index and m.subindex == subindex:
                return m
        raise EtherCATConfigError(f"0x{index:04X}:{subindex} is not mapped")

    def _compute_layout(self) -> int:
        """Process image from 0x1C12/0x1C13 and the mapping objects (as the master configured them);
        an AL status code when a mapping names an object that does not exist."""
        if not self.desc.coe:
            return 0
        try:
            outputs_map, out_bits = self._layout(0x1C12)
        except SdoAbort:
            return AlStatusCode.INVALID_OUTPUT_MAPPING
        try:
            inputs_map, in_bits = self._layout(0x1C13)
        except SdoAbort:
            return AlStatusCode.INVALID_INPUT_MAPPING
        self.outputs_map, self.inputs_map = outputs_map, inputs_map
        self._bind_image()
        self.output_bytes = (out_bits + 7) // 8
        self.input_bytes = (in_bits + 7) // 8
        self._inputs = self._inputs[:self.input_bytes].ljust(self.input_bytes, b"\0")
        self._outputs = bytes(self.output_bytes)
        return 0

    def _layout(self, assign: int) -> tuple[list[MappedEntry], int]:
        out: list[MappedEntry] = []
        bit = 0
        n = int(self.od.get(assign, 0))
        for i in range(1, n + 1):
            pdo = int(self.od.get(assign, i))
            m = int(self.od.get(pdo, 0))
            for j in range(1, m + 1):
                value = int(self.od.get(pdo, j))
                idx, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
                if idx:
                    dtype = self.od.entry(idx, sub).data_type
                    out.append(MappedEntry(idx, sub, bit, bits, dtype))
                bit += bits
        return out, bit


def _get_bits(buf: bytes | bytearray, offset: int, length: int) -> bytes:
    if offset % 8 == 0 and length % 8 == 0:
        return bytes(buf[offset // 8:(offset + length) // 8])
    value = int.from_bytes(buf, "little") >> offset & ((1 << length) - 1)
    return value.to_bytes((length + 7) // 8, "little")


def _set_bits(buf: bytearray, offset: int, length: int, raw: bytes) -> None:
    whole = int.from_bytes(buf, "little")
    mask = ((1 << length) - 1) << offset
    value = (int.from_bytes(raw, "little") << offset) & mask
    buf[:] = ((whole & ~mask) | value).to_bytes(len(buf), "little")
