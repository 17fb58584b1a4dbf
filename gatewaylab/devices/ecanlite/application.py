"""The ECAN-Lite's slave application: profile objects and state rules (13.2, 14), the per-cycle data
path (chapters 6-12) between the frame-stream PDO and the four MCAN channels, SYNC0-scheduled
transmit (8.4, 13.8) and cycle diagnostics (0x9011). The device that owns it (MCAN model, slave,
OTA reset) is :class:`~gatewaylab.devices.ecanlite.device.EcanLiteDevice`.

Sans-I/O: everything runs from the slave's callbacks (outputs written, inputs read, SYNC0, state
changes) and the injected clock. The CAN side (controllers, filters, caches, queues, the maintenance
objects) is :class:`~gatewaylab.devices.ecanlite.model.McanModel`; the byte format is
:mod:`~gatewaylab.devices.ecanlite.stream`; the budget split :mod:`~gatewaylab.devices.ecanlite.budget`.

Per cycle, RxPDO: an image equal to the last one is a no-op; an all-zero image (nothing published
yet) is ignored; ``seq_begin != seq_end`` (torn) is ignored; anything else is decoded whole first and
only then are its CAN_FRAMEs submitted, so a rejected image never puts a frame on the bus. TxPDO: an
image is staged (peeked, not consumed) after every read; when the master has read it, what it
carried is consumed and counted, and the next one is staged (one build per cycle).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.ecanlite import budget as budget_mod
from gatewaylab.devices.ecanlite.image import (
    CHUNKS,
    CYCLE_DIAG,
    RX_MAP,
    RX_PROFILE,
    SI_ACTIVE_AREA,
    SI_ACTIVE_BYTES,
    SI_APPLY,
    SI_BUDGET,
    SI_COMMAND,
    SI_CYCLE_CLEAR,
    SI_ERROR_COUNTER,
    SI_LAST_ERROR,
    SI_LAYOUT_CRC,
    SI_MASK,
    SI_MULTIPLIER,
    SI_OPTIONS,
    SI_OVERFLOW_COUNTER,
    SI_PROFILE,
    SI_PROFILE_WORD,
    SI_SEQUENCE,
    SI_STATUS,
    TX_MAP,
    TX_PROFILE,
)
from gatewaylab.devices.ecanlite.stream import (
    HEADER_SIZE,
    OPTION_MASK,
    PROFILE_MASK,
    TIMESTAMP_UNIT_S,
    VER_IHL,
    CanPacket,
    Commit,
    Direction,
    PdoError,
    ProfileStatus,
    StreamError,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    check_layout,
    commit_state,
    crc16,
    decode_stream,
    encode_stream,
    fold_layout_id,
    packet_size,
    profile_word,
)
from gatewaylab.devices.ecanlite.system import DiagFlag
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.od import Entry, ObjectDictionary, SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from gatewaylab.devices.ecanlite.device import EcanLiteDevice

__all__ = ["EcanLiteApplication"]


OPT_TX_RESULT, OPT_ALIGN4, OPT_NO_CRC16, OPT_APP_BYPASS = 0x01, 0x02, 0x04, 0x08
#: Header flags (chapter 6).
FLAG_TRUNCATED, FLAG_CHANNEL_ERROR, FLAG_TX_RESULT, FLAG_STATUS_CHANGED, FLAG_SEQ_WRAP, FLAG_OVERFLOW_VALID = (
    0x01, 0x02, 0x04, 0x08, 0x10, 0x20)
#: Channel status word bits that make ANY_CHANNEL_ERROR (chapter 7: warn, bus_off, rx/tx pressure).
_STATUS_ERROR_BITS = 0x10 | 0x20 | 0x40 | 0x80
#: Scheduled frames waiting for the next SYNC0 (firmware queue depth, 0xF000:29 TX cache max depth).
SCHED_QUEUE_MAX = 64
#: Smallest packet: ctrl + standard id, no data: bounds how many frames one image can take.
_MIN_PACKET = 4
#: 0x8030:02 TxPDO fine bypass BUILD / COPY and :03 RxPDO STAGE / PARSE (13.2.3; MCAN_READ,
#: TX_RING and MCAN_WRITE act in the MCAN channels).
TX_BYPASS_BUILD, TX_BYPASS_COPY = 1 << 3, 1 << 4
RX_BYPASS_STAGE, RX_BYPASS_PARSE = 1 << 2, 1 << 3


@dataclass(slots=True)
class _Direction:
    """One direction's active profile, status and counters (0x8010 TxPDO, 0x8011 RxPDO)."""

    index: int
    assign: int
    map_base: int
    active: StreamLayout
    status: int = 0
    seq: int = 0
    last_error: int = 0
    errors: int = 0
    overflows: int = 0


@dataclass(slots=True)
class _Staged:
    """The TxPDO image written to the inputs and not yet read: what it carries."""

    counts: dict[int, int]
    results: int
    left: int
    seq: int


@dataclass(slots=True)
class _Scheduled:
    channel: int
    frame: CanFrame
    ref: tuple[int, int]
    offset_ns: int


class EcanLiteApplication(SlaveApplication):
    """Behind the ESC: profile objects, state rules, data path, diagnostics, OTA reset."""

    #: The RxPDO is one byte stream: not stored into its 8*N unit objects every cycle; a CoE read
    #: of a unit decodes it from the outputs image (core, SlaveApplication.store_outputs).
    store_outputs = False

    #: The firmware serves the SM2 and SM3 events on its PDI interrupt (0x9011:01 "PDI IRQ count"),
    #: between frames: the RxPDO stream is parsed and the next TxPDO image staged once the frame has
    #: passed (ESC core, Slave.after_frame), so neither is part of the frame's round trip; the next frame
    #: reads the image staged after this one, as it did when both ran inside the frame.
    outputs_in_frame = False
    inputs_read_in_frame = False

    def __init__(self, device: EcanLiteDevice) -> None:
        self.device = device
        self.model = device.model
        self.clock = device.clock
        self.tx = _Direction(TX_PROFILE, 0x1C13, TX_MAP, StreamLayout.default(Direction.TX))
        self.rx = _Direction(RX_PROFILE, 0x1C12, RX_MAP, StreamLayout.default(Direction.RX))
        self.slave: Slave | None = None
        self._last_rx: bytes = b""
        self._results: deque[TxResultPacket] = deque()
        self._staged: _Staged | None = None
        self._last_status: tuple[int, ...] = (0, 0, 0, 0)
        self._cycle_ref: float | None = None
        self._rotate = 0
        self._scheduled: list[_Scheduled] = []
        self.sched_late_drops = 0
        self.frames_submitted = 0
        # 0x9011
        self.pdi_irqs = 0
        self.sync0_irqs = 0
        self._last_sync0: float | None = None
        self.phase_min: int | None = None
        self.phase_max: int | None = None
        #: 0x9011:06..13 maxima in CPU cycles: output mapping, input mapping, MCAN service, TxPDO
        #: build, RxPDO parse, ESC read, ESC write, schedule service (index = SI - 6).
        self.cost_max = [0] * 8
        self.cpu_hz = 400_000_000

    # ------------------------------------------------------------------ objects
    def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
        """Hooks of 0x8010/0x8011/0x9011, unit objects decoded from the image, then the MCAN model's."""
        self.slave = slave
        for d in (self.tx, self.rx):
            self._publish_active(od, d)
            od.add_validator(d.index, self._validate_profile)
            od.add_reaction(d.index, self._profile_written)
            od.on_read(d.index, self._refresh_profile)
        od.add_reaction(CYCLE_DIAG, self._cycle_written)
        od.on_read(CYCLE_DIAG, self._refresh_cycle)
        self.model.install(slave, od)
        od.put(0x100A, 0, self.model.version_string)
        if (0x8000, 4) in od.values:
            self.cpu_hz = int(od.values[(0x8000, 4)]) or self.cpu_hz

    @staticmethod
    def _validate_profile(entry: Entry, value: Any) -> None:
        if entry.subindex == SI_COMMAND and int(value) & ~0x03:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "command bits 2..7 are reserved (13.2)")

    def _direction(self, index: int) -> _Direction:
        return self.tx if index == TX_PROFILE else self.rx

    def _profile_written(self, entry: Entry, value: Any) -> None:
        d = self._direction(entry.index)
        assert self.slave is not None
        od = self.slave.od
        sub = entry.subindex
        if sub == SI_APPLY:
            od.values[(d.index, SI_APPLY)] = 0
            if int(value) == 1:
                self._apply(d)
        elif sub == SI_COMMAND:
            od.values[(d.index, SI_COMMAND)] = 0
            if int(value) & 0x01:
                self._reset_session(d)
            if int(value) & 0x02:
                d.last_error = d.errors = d.overflows = 0
                if d.status in (ProfileStatus.ENCAPSULATION_ERROR, ProfileStatus.OVERFLOW):
                    d.status = ProfileStatus.OK
        elif SI_MULTIPLIER <= sub <= SI_OPTIONS:
            d.status = ProfileStatus.PENDING_APPLY

    def _requested(self, d: _Direction) -> tuple[int, int, int, int, int]:
        assert self.slave is not None
        v = self.slave.od.values
        i = d.index
        return (int(v[(i, SI_MULTIPLIER)]), int(v[(i, SI_MASK)]), int(v[(i, SI_PROFILE)]), int(v[(i, SI_BUDGET)]),
                int(v[(i, SI_OPTIONS)]))

    def _apply(self, d: _Direction) -> None:
        """13.2 / 14.2: validate the requested profile; the active one changes only on status 0."""
        assert self.slave is not None
        n, mask, profile, budget, options = self._requested(d)
        merit = int(check_layout(n, mask, profile, budget, options, max_multiplier=CHUNKS))
        if self.slave.state == AlState.OP:
            d.status = ProfileStatus.INVALID_STATE
        elif merit:
            d.status = ProfileStatus(merit)
        elif not self._assignment_matches(d, n):
            d.status = ProfileStatus.MAPPING_RELOAD_REQUIRED
        else:
            new = StreamLayout(multiplier=n, channel_mask=mask, profile=profile, budget_policy=budget, options=options,
                               direction=Direction.TX if d is self.tx else Direction.RX)
            if new != d.active:
                d.active = new
                self._reset_session(d)
            d.status = ProfileStatus.OK
            self._publish_active(self.slave.od, d)

    def _assignment_matches(self, d: _Direction, n: int) -> bool:
        """0x1C12/0x1C13 must assign exactly the first ``n`` chunks in order (5.1, 5.4.1)."""
        assert self.slave is not None
        v = self.slave.od.values
        if int(v[(d.assign, 0)]) != n:
            return False
        return all(int(v[(d.assign, i + 1)]) == d.map_base + i for i in range(n))

    def _reset_session(self, d: _Direction) -> None:
        d.seq = 0
        d.last_error = 0
        if d.status in (ProfileStatus.ENCAPSULATION_ERROR, ProfileStatus.OVERFLOW):
            d.status = ProfileStatus.OK
        if d is self.rx:
            self._last_rx = b""
            self._scheduled.clear()
        else:
            self._results.clear()
            self._staged = None

    @staticmethod
    def _publish_active(od: ObjectDictionary, d: _Direction) -> None:
        a = d.active
        od.put(d.index, SI_ACTIVE_BYTES, a.pdo_bytes)
        od.put(d.index, SI_ACTIVE_AREA, a.frame_area_bytes)
        od.put(d.index, SI_LAYOUT_CRC, a.layout_crc)
        od.put(d.index, SI_PROFILE_WORD, a.profile_word)

    def _refresh_profile(self, index: int, subindex: int) -> None:
        d = self._direction(index)
        v = self.slave.od.values if self.slave is not None else {}
        v[(index, SI_STATUS)] = d.status
        v[(index, SI_SEQUENCE)] = d.seq & 0xFFFF
        v[(index, SI_LAST_ERROR)] = d.last_error
        v[(index, SI_ERROR_COUNTER)] = d.errors & 0xFFFFFFFF
        v[(index, SI_OVERFLOW_COUNTER)] = d.overflows & 0xFFFFFFFF

    def _cycle_written(self, entry: Entry, value: Any) -> None:
        if entry.subindex == SI_CYCLE_CLEAR and self.slave is not None:
            self.slave.od.values[(CYCLE_DIAG, SI_CYCLE_CLEAR)] = 0
            if int(value) == 1:
                self.pdi_irqs = self.sync0_irqs = 0
                self.phase_min = self.phase_max = None
                self.cost_max = [0] * len(self.cost_max)

    def _refresh_cycle(self, index: int, subindex: int) -> None:
        assert self.slave is not None
        v = self.slave.od.values
        v[(CYCLE_DIAG, 1)] = self.pdi_irqs & 0xFFFFFFFF
        v[(CYCLE_DIAG, 2)] = self.sync0_irqs & 0xFFFFFFFF
        v[(CYCLE_DIAG, 4)] = _i32(self.phase_min or 0)
        v[(CYCLE_DIAG, 5)] = _i32(self.phase_max or 0)
        for i in range(8):
            v[(CYCLE_DIAG, 6 + i)] = min(self.cost_max[i], 0xFFFFFFFF)

    def _cost(self, slot: int, t0: float) -> None:
        cycles = round((self.clock.now() - t0) * self.cpu_hz)
        if cycles > self.cost_max[slot]:
            self.cost_max[slot] = cycles

    # ------------------------------------------------------------------ states (14, 14.2)
    def on_transition(self, slave: Slave, old: AlState, new: AlState) -> int:
        """SAFEOP -> OP only when the SM2/SM3 lengths the master mapped equal the active profiles."""
        if new == AlState.OP:
            if slave.output_bytes != self.rx.active.pdo_bytes:
                return AlStatusCode.INVALID_OUTPUT_CONFIG
            if slave.input_bytes != self.tx.active.pdo_bytes:
                return AlStatusCode.INVALID_INPUT_CONFIG
        return 0

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        """Entering SAFEOP publishes a first TxPDO image; leaving OP forgets the RxPDO session."""
        if new in (AlState.SAFEOP, AlState.OP) and old in (AlState.INIT, AlState.PREOP):
            self._staged = None
            self._stage()
        if new != AlState.OP:
            self._last_rx = b""
            self._scheduled.clear()

    # ------------------------------------------------------------------ RxPDO -> CAN
    def on_outputs(self, slave: Slave, data: bytes) -> None:
        """One RxPDO image (chapter 6 reception rules), then the TxPDO restaged with the newest state."""
        t0 = self.clock.now()
        self.pdi_irqs += 1
        if self._last_sync0 is not None:
            phase = round((t0 - self._last_sync0) * self.cpu_hz)
            self.phase_min = phase if self.phase_min is None else min(self.phase_min, phase)
            self.phase_max = phase if self.phase_max is None else max(self.phase_max, phase)
        if data != self._last_rx and not self.model.system.test.rx_bypass & RX_BYPASS_STAGE:
            self._rx_image(data)  # (0x8030:03 STAGE: the image is not taken in at all, 13.2.3)
            self._cost(4, t0)
        self._cost(0, t0)
        if self._staged is None:  # else the image staged after the last read stands (one build per cycle)
            t1 = self.clock.now()
            self._stage()
            self._cost(3, t1)

    def _rx_image(self, data: bytes) -> None:
        rx = self.rx
        if not any(data):
            self._last_rx = data
            return  # the master has not published anything yet (an all-zero image after OP)
        try:
            commit = commit_state(data, self._last_rx or None)
        except StreamError as exc:
            self._error(rx, exc.pdo_error)
            return
        if commit is Commit.TORN:
            return  # seq_begin != seq_end: ignore this cycle (6.1)
        self._last_rx = data
        if commit is Commit.SAME:
            return  # the same image again, beyond payload_len (13.8: idempotent no-op)
        if commit is Commit.DUPLICATE:
            self._error(rx, PdoError.DUPLICATE_SEQUENCE)
            return
        test = self.model.system.test
        if test.rx_bypass & RX_BYPASS_PARSE:
            # 0x8030:03 PARSE (13.2.3): the header is taken (sequence), the payload is not parsed
            if data[0] != VER_IHL:
                self._error(rx, PdoError.BAD_HEADER)
            else:
                rx.seq = int.from_bytes(data[2:4], "little")
            return
        try:
            if test.crc_policy:
                data = _crc_policy_rx(data, rx.active, force=test.crc_policy == 1)
            decoded = decode_stream(data, rx.active)
        except StreamError as exc:
            code: int = exc.pdo_error
            if code == PdoError.ACTIVE_AREA:
                code = _layout_error(data, rx.active)
            self._error(rx, code)
            return
        seq = decoded.seq
        rx.seq = seq
        frames = decoded.frames
        if not frames:
            return
        if any(p.scheduled for p in frames) and not self._sync0_active():
            self._error(rx, PdoError.BAD_SCHEDULE)  # no SYNC0 to schedule against (13.8)
            return
        if rx.active.options & OPT_APP_BYPASS or test.app_bypass & 2:
            return  # 9.1 / 0x8030:06 Rx: the RxPDO does not enter the MCAN path
        channels = self.model.channels
        tx_result = bool(self.tx.active.options & OPT_TX_RESULT)
        results = self._results
        for index, p in enumerate(frames):
            ref = (seq, index)
            ch = p.channel
            if p.scheduled:
                if len(self._scheduled) >= SCHED_QUEUE_MAX:
                    self._maintenance_flag(DiagFlag.SCHED_QUEUE_FULL)
                    rx.overflows += 1
                    if tx_result:
                        results.append(TxResultPacket(ch, seq, index, TxResultCode.TX_FIFO_FULL))
                    continue
                self._scheduled.append(_Scheduled(ch, p.frame, ref, p.offset_ns))
                continue
            code = channels[ch].submit(p.frame, ref)
            self.frames_submitted += 1
            if code and tx_result:
                results.append(TxResultPacket(ch, seq, index, TxResultCode(code)))

    def _error(self, d: _Direction, code: int) -> None:
        d.last_error = int(code)
        d.errors += 1
        d.status = ProfileStatus.ENCAPSULATION_ERROR

    def _sync0_active(self) -> bool:
        return self._sync0_cycle() > 0

    def _sync0_cycle(self) -> float:
        """The SYNC0 period the ESC's DC unit runs (0x0981 activation, 0x09A0 cycle); 0 = off."""
        assert self.slave is not None
        return self.slave.esc.sync0_period

    def _maintenance_flag(self, flag: DiagFlag) -> None:
        """Latch a 0xB000:06 legacy diag flag (13.7) in the maintenance model."""
        self.model.system.diag_flags |= flag

    # ------------------------------------------------------------------ SYNC0 scheduled transmit
    def on_sync0(self, slave: Slave, t: float) -> None:
        """The frames queued before this SYNC0 go out at ``t + offset_ns`` (8.4, 13.8); a target phase
        that is already past, or lies beyond this SYNC0 cycle, is dropped (SCHED_LATE_DROP)."""
        self.sync0_irqs += 1
        self._last_sync0 = t
        if not self._scheduled:
            return
        t0 = self.clock.now()
        due, self._scheduled = self._scheduled, []
        cycle = self._sync0_cycle()
        tx_result = bool(self.tx.active.options & OPT_TX_RESULT)
        for s in due:
            when = t + s.offset_ns * 1e-9
            if when < t0 or (cycle and s.offset_ns * 1e-9 >= cycle):
                self.sched_late_drops += 1
                self.rx.overflows += 1
                self._maintenance_flag(DiagFlag.SCHED_LATE_DROP)
                if tx_result:
                    self._results.append(TxResultPacket(s.channel, s.ref[0], s.ref[1], TxResultCode(2)))
                continue
            self.clock.call_at(when, self._send_scheduled, s)
        self._cost(7, t0)

    def _send_scheduled(self, s: _Scheduled) -> None:
        code = self.model.channels[s.channel].submit(s.frame, s.ref)
        self.frames_submitted += 1
        if code and self.tx.active.options & OPT_TX_RESULT:
            self._results.append(TxResultPacket(s.channel, s.ref[0], s.ref[1], TxResultCode(code)))

    # ------------------------------------------------------------------ CAN -> TxPDO
    def on_inputs_read(self, slave: Slave) -> None:
        """The master read the staged image: consume what it carried, count, stage the next one."""
        t0 = self.clock.now()
        self.pdi_irqs += 1
        staged = self._staged
        if staged is not None:
            channels = self.model.channels
            for ch, n in staged.counts.items():
                if n:
                    channels[ch].consume(n)
            for _ in range(min(staged.results, len(self._results))):
                self._results.popleft()
            if staged.left:
                self.tx.overflows += 1
                self.tx.status = ProfileStatus.OVERFLOW
            self.tx.seq = staged.seq
        self.model.on_cycle(t0)
        self._cost(2, t0)  # MCAN PDO service: consume + channel tick
        self._staged = None
        t1 = self.clock.now()
        self._stage()
        self._cost(3, t1)
        self._cost(1, t0)

    def _collect_results(self) -> None:
        """TX results the channels finished since the last image (chapter 10), when TX_RESULT is on."""
        want = self.tx.active.options & OPT_TX_RESULT
        results = self._results
        for ch in self.model.channels:
            done = ch.take_tx_results()
            if want:
                for ref, code in done:
                    if isinstance(ref, tuple):
                        results.append(TxResultPacket(ch.index, ref[0], ref[1], TxResultCode(code)))

    def _stage(self) -> None:
        """Build the next TxPDO image from the channels' oldest frames (chapter 12 budget)."""
        slave = self.slave
        assert slave is not None
        layout = self.tx.active
        if slave.input_bytes != layout.pdo_bytes or slave.state not in (AlState.SAFEOP, AlState.OP):
            return
        seq = (self.tx.seq + 1) & 0xFFFF
        channels = self.model.channels
        self._collect_results()
        status_words = tuple(ch.status_word() for ch in channels)
        flags = 0
        if seq == 0:
            flags |= FLAG_SEQ_WRAP
        if status_words != self._last_status:
            flags |= FLAG_STATUS_CHANGED
        if any(w & _STATUS_ERROR_BITS or (w & 0x07) in (3, 4) for w in status_words):
            flags |= FLAG_CHANNEL_ERROR
        area = layout.frame_area_bytes
        packets: list[CanPacket | TxResultPacket] = []
        n_results = 0
        test = self.model.system.test
        # 9.1 APP_BYPASS, 0x8030:06 Tx and 0x8030:02 BUILD: a header (status words) without packets
        bypass = bool(layout.options & OPT_APP_BYPASS or test.app_bypass & 1 or test.tx_bypass & TX_BYPASS_BUILD)
        if layout.options & OPT_TX_RESULT and not bypass:
            for r in self._results:
                size = packet_size(r, layout)
                if size > area or n_results == 255:
                    break
                area -= size
                packets.append(r)
                n_results += 1
        counts: dict[int, int] = {}
        left = 0
        if not bypass:
            limit = area // _MIN_PACKET + 1
            pending: dict[int, list[int]] = {}
            peeked: dict[int, list[CanPacket]] = {}
            now = self.clock.now()
            ref = self._cycle_ref if self._cycle_ref is not None else now
            self._cycle_ref = now
            tsf = Tsf.DELTA16 if layout.allows_tsf(Tsf.DELTA16) else Tsf.NONE
            mask = layout.channel_mask
            for ch in channels:
                if mask >> ch.index & 1 and ch.controller is not None:
                    frames = ch.peek(limit)
                    if frames:
                        pk = [CanPacket.from_frame(ch.index, rf.frame, tsf=tsf,
                                                   timestamp=round((rf.t - ref) / TIMESTAMP_UNIT_S) & 0xFFFF
                                                   if tsf else 0) for rf in frames]
                        peeked[ch.index] = pk
                        pending[ch.index] = [packet_size(p, layout) for p in pk]
            if pending:
                alloc = budget_mod.allocate(layout.budget_policy, area, layout.channels, pending,
                                            max_packets=255 - n_results, rotate=self._rotate)
                self._rotate += 1
                for ch_index, n in alloc.counts.items():
                    if n:
                        counts[ch_index] = n
                        packets.extend(peeked[ch_index][:n])
                left = alloc.left_behind  # peeked (within the drain budgets) but not packed
        if left:
            flags |= FLAG_TRUNCATED | FLAG_OVERFLOW_VALID
        image = encode_stream(layout, seq, packets, status_words=status_words, flags=flags, overflow_sat=left)
        if test.tx_bypass & TX_BYPASS_COPY:
            # 0x8030:02 COPY (13.2.3): built, not published: the master keeps reading the last image
            # and nothing is consumed
            self._staged = _Staged({}, 0, 0, self.tx.seq)
            return
        if test.crc_policy:
            image = _with_crc(image, test.crc_policy == 1)
        self._last_status = status_words
        self._staged = _Staged(counts, n_results, left, seq)
        if test.payload_only & 1:
            # 0x8030:05 Tx: only the header and the valid payload are written (9.1 PAYLOAD_ONLY)
            slave.write_inputs(image[:HEADER_SIZE + int.from_bytes(image[6:8], "little")])
        else:
            slave.write_inputs(image)


def _with_crc(image: bytes, on: bool) -> bytes:
    """0x8030:04 CRC test policy on a built image: 1 force CRC16 (crc_alg 1 + CRC-16/CCITT-FALSE
    over the payload), 2 force no CRC16 (crc_alg 0, payload_crc16 0), whatever 9.1 NO_CRC16 says."""
    b = bytearray(image)
    n = int.from_bytes(b[6:8], "little")
    b[8:10] = (crc16(b[HEADER_SIZE:HEADER_SIZE + n]) if on else 0).to_bytes(2, "little")
    b[15] = 1 if on else 0
    return bytes(b)


def _crc_policy_rx(data: bytes, layout: StreamLayout, *, force: bool) -> bytes:
    """0x8030:04 on an RxPDO image: 1 force CRC16 = the image must carry crc_alg 1 and a good
    payload_crc16 even with NO_CRC16 (else LastPDOError 14 / 15); 2 force no CRC16 = the CRC is not
    checked. Returns the image as the active profile's decoder expects it."""
    n = int.from_bytes(data[6:8], "little")
    if n > len(data) - HEADER_SIZE:
        return data                      # the decoder reports the overrun
    calc = crc16(data[HEADER_SIZE:HEADER_SIZE + n])
    if force:
        if data[15] != 1:
            raise StreamError(PdoError.BAD_HEADER)
        if int.from_bytes(data[8:10], "little") != calc:
            raise StreamError(PdoError.BAD_CRC)
    return _with_crc(data, layout.crc_enabled)


def _layout_error(data: bytes, layout: StreamLayout) -> PdoError:
    """Refine 'active area' (layout_id / channel_mask differ, 6.1): the fold of 5.4.4.1 keeps the
    profile's low 3 bits (13..15) and the option flags (5..12, given the header's channel mask)
    apart from everything else, so an image built for a profile outside 0xF000:12 is 9 'unsupported
    profile' and one with option bits outside 0xF000:15 is 11 'unsupported option'."""
    if len(data) < HEADER_SIZE:
        return PdoError.ACTIVE_AREA
    layout_id = int.from_bytes(data[10:12], "little")
    base = fold_layout_id(profile_word(layout.multiplier, data[12], 0, layout.budget_policy, 0))
    x = layout_id ^ base
    if x & 0x1F:
        return PdoError.ACTIVE_AREA      # multiplier, budget or profile bits 3..5: ambiguous
    profile, options = x >> 13 & 7, x >> 5 & 0xFF
    if not PROFILE_MASK >> profile & 1:
        return PdoError.UNSUPPORTED_PROFILE
    if options & ~OPTION_MASK:
        return PdoError.UNSUPPORTED_OPTION
    return PdoError.ACTIVE_AREA


def _i32(value: int) -> int:
    return max(-0x80000000, min(0x7FFFFFFF, value))
