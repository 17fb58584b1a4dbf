"""The esd queue API on an ECAN-Lite MCAN channel (docs/migration-esd-to-ecanlite.md).

:class:`EsdQueueOnEcanLite` implements :class:`~gatewaylab.hosts.esd_can_ethercat.EsdQueueApi`
(what code written against the esd host library's :class:`EsdHost` calls) over the ECAN-Lite host
library's :class:`~gatewaylab.hosts.ecanlite.port.McanPort` on one MCAN channel, so that

    host = EsdHost(backend, position)              # esd CAN-EtherCAT
    host = EsdQueueOnEcanLite(backend, position)   # ECAN-Lite, MCAN0 (``channel=K`` for another)

is the only line that changes. How each esd notion is carried (docs/migration-esd-to-ecanlite.md,
'The esd queue API on the ECAN-Lite'):

* configuration: the :class:`EsdConfig` becomes the esd startup writes (0xF800, 0x8000, 0x8001,
  0x1C13) and goes through the part-1 translator (:func:`gatewaylab.migrate.translate.translate`):
  bit rate and node mode, PDO multiplier N from the queue sizes, filter areas -> filter lists; the
  adapter writes the profile (0x1C12/0x1C13, 0x8010/0x8011 with TX_RESULT on, 0x8010:07 bit 0), the
  channel writes follow with their apply status check, and the channel's data path policy
  (0x802x, 13.2.2) drains the whole RX cache every cycle, as the esd delivers a whole Rx batch.
* Tx (the bookkeeping is the sans-I/O :class:`~.txbook.TxBook`): frames wait in order on the host,
  each with its transaction number (1..FFFFh, as the esd's);
  a batch of at most the Tx queue size (0x8000:22) goes into one RxPDO image whole, and only when
  the MCAN TX FIFO (0x800x:70) has room for all of it -- otherwise it waits, never split.
  *Accepted* = the image carrying it was exchanged with a complete working counter. Each frame's
  TX_RESULT (chapter 10) is matched by (RefPacketSeq, RefFrameIndex) in a table to its transaction
  number; *completed* is the prefix of transactions with a final result (0 OK or a failure), as the
  esd's input Tx Transaction Number completes a frame and every one before it. A failed ResultCode
  (2 bus busy, 3 invalid channel, 4 TX FIFO full, 5 bus off) completes the frame and counts in
  'CANDriver Aborted Frames', as the esd counts a frame it did not send in 0x2010:37;
  :meth:`EsdQueueOnEcanLite.result` tells which code a transaction got.
* Rx: every TxPDO's CAN_FRAME packets of the channel, stamped with the time of the cycle that read
  them, ``batch`` = the TxPDO sequence number.
* status: 0x9000+K (ECR TEC/REC, PSR bus off / warning) and 0x9020+K:05 (RX dropped) by SDO;
  :meth:`~EsdQueueOnEcanLite.pdo_status` from the chapter-7 channel status word in every TxPDO header.
* statistics: the esd 0x2010 names, from 0x9000+K / 0x9020+K and the host's own counts; the ones
  with no ECAN-Lite source are None (:data:`NO_SOURCE`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError, LocalError, ProtocolError
from gatewaylab.devices.ecanlite.stream import CanPacket, TxResultCode
from gatewaylab.devices.esd_can_ethercat.bitrate import NTCAN_NO_BAUDRATE
from gatewaylab.devices.esd_can_ethercat.codec import CanStatus
from gatewaylab.devices.esd_can_ethercat.objects import STATISTICS
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ecanlite.adapter import AdapterConfig, EcanAdapter, SlaveConfig, StartupSdo, find_ecanlite
from gatewaylab.hosts.ecanlite.port import McanPort, PortConfig, drain_all_sdos
from gatewaylab.hosts.esd_can_ethercat.config import BitRate, EsdConfig, FilterArea, QueueLayout, for_bitrate
from gatewaylab.hosts.esd_can_ethercat.gateway import SDO_ATTEMPTS, SDO_RETRY_WAIT
from gatewaylab.hosts.esd_can_ethercat.handshake import (
    DEFAULT_RX_LIMIT,
    DEFAULT_TX_LIMIT,
    TN_MODULO,
    RxFrame,
    RxOverflowError,
)
from gatewaylab.hosts.esd_can_ethercat.loop import DEFAULT_TIMEOUT, HostLoop
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout
from gatewaylab.hosts.ethercat.states import walk_to
from gatewaylab.migrate.eni import InitCmd
from gatewaylab.migrate.translate import DEFAULT_FALLBACK_RATE, Translation, translate
from gatewaylab.migrate.txbook import TxBook

__all__ = ["NO_SOURCE", "EsdQueueOnEcanLite", "esd_writes"]

#: 0x8001..0x8004 channel config, 0x9000.. info, 0x9020.. diagnostics (0x8021.. data path: drain_all_sdos).
CONFIG_BASE, INFO_BASE, DIAG_BASE = 0x8001, 0x9000, 0x9020
#: Chapter 7 status word bits.
SW_STATE, SW_WARN, SW_BUS_OFF, SW_RX_PRESSURE = 0x07, 0x10, 0x20, 0x40
STATE_BUSOFF = 3
#: M_CAN ECR (TEC 0..7, REC 8..14, RP 15, CEL 16..23) and PSR (EW 6, BO 7) bits.
PSR_EW, PSR_BO, ECR_RP = 0x40, 0x80, 0x8000
#: The 0x2010 names the ECAN-Lite has no source for: statistics() gives None (docs/decisions.md).
NO_SOURCE = frozenset(STATISTICS[s] for s in (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x10, 0x11, 0x12,
                                              0x13, 0x14, 0x15, 0x16, 0x20, 0x21, 0x34))
#: An SDO service without an answer, or a late answer to an earlier one: repeated (as EsdHost).
_RETRYABLE = (MasterTimeout, ProtocolError)


def esd_writes(cfg: EsdConfig) -> list[InitCmd]:
    """The esd startup writes :meth:`EsdHost.configure` makes for ``cfg`` (0xF800, 0x8000, 0x8001, 0x1C13)."""
    def u(index: int, sub: int, value: int, size: int) -> InitCmd:
        return InitCmd(index, sub, value.to_bytes(size, "little"))
    w = []
    if cfg.bitrate.index == 0xFF:
        w.append(u(0xF800, 5, cfg.bitrate.api, 4))
    w.append(u(0xF800, 2, cfg.bitrate.index, 1))
    w += [u(0x8000, 0x20, cfg.flags, 2), u(0x8000, 0x21, cfg.rx_queue, 1), u(0x8000, 0x22, cfg.tx_queue, 1),
          u(0x8000, 0x23, cfg.local_rx_queue, 2), u(0x8000, 0x24, cfg.local_tx_queue, 2), u(0x8001, 0, 0, 1)]
    w += [u(0x8001, i, a.value, 8) for i, a in enumerate(cfg.filters, start=1)]
    w.append(u(0x8001, 0, len(cfg.filters), 1))
    pdos = (0x1A00, 0x1A85) if cfg.status_pdo else (0x1A00,)
    w += [u(0x1C13, 0, 0, 1), *(u(0x1C13, i, p, 2) for i, p in enumerate(pdos, start=1)), u(0x1C13, 0, len(pdos), 1)]
    return w


@dataclass(slots=True)
class _Counts:
    """The host's own counts behind the statistics (zeroed by reset_statistics)."""

    tx_requested: int = 0
    tx_ok: int = 0
    tx_failed: int = 0
    rx: int = 0
    rx_std: int = 0
    rx_std_rtr: int = 0
    rx_ext: int = 0
    rx_ext_rtr: int = 0
    tx_std: int = 0
    tx_std_rtr: int = 0
    tx_ext: int = 0
    tx_ext_rtr: int = 0


def _count_kind(c: _Counts, prefix: str, frame: CanFrame) -> None:
    name = f"{prefix}_{'ext' if frame.extended else 'std'}{'_rtr' if frame.rtr else ''}"
    setattr(c, name, getattr(c, name) + 1)


class EsdQueueOnEcanLite(HostLoop):
    """The esd queue API (:class:`EsdQueueApi`) on MCAN ``channel`` of the ECAN-Lite at ``position``."""

    def __init__(self, backend: MasterBackend, position: int = 0, *, channel: int = 0, cycle_time: float = 0.001,
                 external_cycle: bool = False, check_identity: bool = True, tx_limit: int = DEFAULT_TX_LIMIT,
                 rx_limit: int = DEFAULT_RX_LIMIT, fallback_rate: int = DEFAULT_FALLBACK_RATE) -> None:
        if not 0 <= channel <= 3:
            raise LocalError(f"MCAN channel {channel} is not 0..3")
        if not 0 < tx_limit < TN_MODULO // 2:
            raise LocalError(f"tx_limit must be 1..{TN_MODULO // 2 - 1}")
        super().__init__(backend, position, cycle_time, external_cycle)
        self.channel = channel
        self.tx_limit = tx_limit
        #: Received frames the host keeps before counting ``rx_over_limit`` (none is dropped: the
        #: ECAN-Lite has no acknowledgement that could hold them back in the gateway).
        self.rx_limit = rx_limit
        self.fallback_rate = fallback_rate
        self.config: EsdConfig | None = None
        self.layout: QueueLayout | None = None
        self.translation: Translation | None = None
        self.adapter: EcanAdapter | None = None
        self.port: McanPort | None = None
        #: MCAN TX FIFO elements (0x800x:70): frames in flight at most.
        self.tx_room = 0
        #: SDO services repeated after a timeout or a late answer (reads, window writes).
        self.sdo_retries = 0
        #: Frames received while the host already held ``rx_limit`` (kept anyway).
        self.rx_over_limit = 0
        self._running = False
        self.book: TxBook | None = None
        self._reset_queues()
        self._counts = _Counts()
        self._base_dropped = 0
        self._base_cel = 0
        self._reported_dropped = 0
        if check_identity and position not in {s.position for s in find_ecanlite(backend)}:
            raise ConfigError(f"slave {position} is not an ECAN-Lite")

    # ------------------------------------------------------------------ SDO helpers
    def _retry(self, call: Callable[[], bytes | None]) -> bytes | None:
        """An idempotent SDO service, repeated after a timeout or a late answer (as EsdHost's reads)."""
        for attempt in range(SDO_ATTEMPTS - 1):
            try:
                return call()
            except _RETRYABLE:
                self.sdo_retries += 1
                self.clock.wait(SDO_RETRY_WAIT * (attempt + 1))
        return call()      # the last attempt's error reaches the caller

    def _up(self, index: int, sub: int) -> int:
        raw = self._retry(lambda: self.backend.sdo_upload(self.position, index, sub))
        assert raw is not None
        return int.from_bytes(raw, "little")

    def _down(self, index: int, sub: int, value: int, size: int) -> None:
        self._retry(lambda: self.backend.sdo_download(self.position, index, sub, value.to_bytes(size, "little")))

    # ------------------------------------------------------------------ configuration
    def to_preop(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        """The slave in PREOP (from BOOT through INIT); the queues stop until :meth:`start`."""
        with self._lock:
            self._running = False
        walk_to(self.backend, self.position, AlState.PREOP, timeout)

    def configure(self, config: EsdConfig | None = None, /, **changes: Any) -> QueueLayout:
        """Translate ``config`` (or EsdConfig(**changes)) and write it in PREOP: the profile (5.4.3
        phases B-D with readback), the channel (13.4, apply status checked) and its data path policy
        (13.2.2). Returns the esd's queue layout with the ECAN-Lite's 128 x N bytes each way.
        ConfigError when the Tx queue size exceeds the TX FIFO (a batch could not be taken whole)."""
        cfg = replace(config, **changes) if config is not None else EsdConfig(**changes)
        if cfg.tx_queue < 1 or cfg.rx_queue < 1:
            raise ConfigError("the Tx and Rx queue sizes must be at least 1 (5.1.5.5)")
        self.to_preop()
        tr = translate(esd_writes(cfg), self.channel, fallback_rate=self.fallback_rate)
        base = CONFIG_BASE + self.channel
        on_bus = any(c.index == base for c in tr.cmds)
        mask = 1 << self.channel if on_bus else 0
        slave = SlaveConfig(self.position, tr.multiplier, tx_mask=mask, rx_mask=mask)
        adapter = EcanAdapter(self.backend, AdapterConfig((slave,), cycle_us=max(1, round(self.cycle_time * 1e6))))
        port = McanPort(adapter, PortConfig(channels={}, tx_mask=mask, rx_mask=mask, tx_result=True))
        p = self.position
        for c in tr.cmds:
            if c.index == base:
                adapter.add_startup_sdo(StartupSdo(p, c.index, c.subindex, c.data, False, c.comment))
        if on_bus:
            adapter.add_startup_sdo(StartupSdo.expect(p, base, 2, b"\x00", f"MCAN{self.channel} apply status"))
            for sdo in drain_all_sdos(p, self.channel):      # the esd hands over a whole Rx batch
                adapter.add_startup_sdo(sdo)
        adapter.run_startup_queue()
        tx_room = self._up(base, 70)
        if cfg.tx_queue > tx_room:
            raise ConfigError(f"Tx queue size {cfg.tx_queue} (0x8000:22) exceeds the MCAN TX FIFO of {tx_room} "
                              f"elements (0x{base:04X}:46): a batch could not be taken whole")
        area = slave.rx_layout.frame_area_bytes
        worst = cfg.tx_queue * CanPacket.of(self.channel, 0, cfg.extended, data=bytes(8)).raw_size
        if worst > area:
            raise ConfigError(f"a batch of {cfg.tx_queue} frames needs {worst} B, the RxPDO frame area has {area} B "
                              f"(N = {tr.multiplier}, at most 24)")
        n_bytes = 128 * tr.multiplier
        layout = QueueLayout(cfg.extended, cfg.tx_queue, cfg.rx_queue, cfg.status_pdo, n_bytes, n_bytes)
        with self._lock:
            self.config, self.layout, self.translation = cfg, layout, tr
            self.adapter, self.port, self.tx_room = adapter, port, tx_room
        return layout

    def set_bitrate(self, bitrate: BitRate) -> None:
        """The bit rate part of the translation written to the channel and applied (13.4: in any
        state, as the esd's 0xF800). A change to or from 'no baud rate' needs :meth:`configure`."""
        if self.config is None or self.translation is None:
            raise LocalError("configure() first")
        cfg = replace(self.config, bitrate=bitrate)
        tr = translate(esd_writes(cfg), self.channel, fallback_rate=self.fallback_rate)
        base = CONFIG_BASE + self.channel
        cmds = [c for c in tr.cmds if c.index == base and (c.subindex in (7, 8, 15, 16, 19) or 21 <= c.subindex <= 28)]
        if not cmds:
            raise ConfigError("no baud rate takes the channel off the PDO (0x8010/0x8011:04): use configure()")
        for c in cmds:
            self._down(c.index, c.subindex, c.value, len(c.data))
        self._down(base, 1, 1, 1)
        status = self._up(base, 2)
        if status:
            raise ConfigError(f"0x{base:04X}:02 apply status {status} for {tr.bitrate} bit/s (13.4)")
        self.config, self.translation = cfg, tr

    # ------------------------------------------------------------------ start / stop
    def start(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Map, DC (none), SAFEOP, OP (the adapter's start without writing the startup queue again)."""
        adapter = self.adapter
        if adapter is None:
            raise LocalError("configure() first")
        adapter.config = replace(adapter.config, skip_sdo_config=True)
        adapter.started = False
        adapter.start(op_timeout=timeout)
        with self._lock:
            self._reset_queues()
            self._running = True

    def stop(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Back to PREOP: the channel stops; queued frames stay unsent."""
        self.to_preop(timeout)

    def _reset_queues(self) -> None:
        cfg = self.config
        self.book = (TxBook(cfg.tx_queue, self.tx_room, extended=cfg.extended, tx_limit=self.tx_limit)
                     if cfg is not None else None)
        self._handed: list[tuple[int, int, CanFrame]] = []   # (port request, tn, frame): taken, not published
        self._received: deque[RxFrame] = deque()
        self._status_word = 0
        self._status_seen = False                        # a TxPDO header was read since start
        self._pressure_seen = False
        self._overflow_new = False

    @property
    def unmatched_results(self) -> int:
        """TX_RESULTs whose (RefPacketSeq, RefFrameIndex) named no frame of the table."""
        return self.book.unmatched if self.book is not None else 0

    @property
    def tx_held(self) -> int:
        """Cycles a batch waited: the TX FIFO had no room for all of it, or the channel was bus off."""
        return self.book.held if self.book is not None else 0

    # ------------------------------------------------------------------ the cycle
    def _require(self) -> tuple[EcanAdapter, McanPort, TxBook]:
        if not self._running or self.adapter is None or self.port is None or self.book is None:
            raise LocalError("the queues are not running: configure(), then start()")
        return self.adapter, self.port, self.book

    def cycle(self) -> bool:
        """One process-data cycle: the next batch into the RxPDO, exchange, the TxPDO parsed
        (frames, TX_RESULTs, the channel status word). False when the working counter was wrong."""
        _adapter, port, book = self._require()
        with self._lock:
            self._fill(port, book)
        # after a wrong working counter the Port sends the image carrying the batch again (13.8)
        status = port.cycle_end()
        port.cycle_begin()
        self.cycles += 1
        with self._lock:
            if self._handed and port.pending(0) == 0:
                where = {t.request: (t.seq, t.index) for t in port.tickets(0)}
                book.published((tn, f, where[request]) for request, tn, f in self._handed)
                self._handed.clear()
            if not status.complete:
                self.wkc_errors += 1
                self._bad_cycles += 1
                return False
            self._bad_cycles = 0
            self._absorb(port, book)
        return True

    def _fill(self, port: McanPort, book: TxBook) -> None:
        """A batch into the next image, whole, when the TX FIFO has room for it; held while bus off."""
        sw = self._status_word
        for tn, f in book.take_batch(hold=bool(sw & SW_BUS_OFF) or sw & SW_STATE == STATE_BUSOFF):
            packet = CanPacket.of(self.channel, f.can_id, f.extended, False, False, f.rtr, False, f.data,
                               dlc=f.dlc if f.rtr else -1)
            self._handed.append((port.send_packet(0, packet), tn, f))

    def _absorb(self, port: McanPort, book: TxBook) -> None:
        """After a cycle with a complete working counter: acceptance, TX_RESULTs, received frames, status."""
        cfg = self.config
        assert cfg is not None
        c = self._counts
        c.tx_requested += book.accept()
        for res in port.take_tx_results():
            done = book.on_result(res.seq, res.index, res.code)
            if done is None:
                continue
            if res.code == TxResultCode.OK:
                c.tx_ok += 1
                _count_kind(c, "tx", done[1])
            else:
                c.tx_failed += 1
        for r in port.receive():
            if r.channel != self.channel:
                continue
            f = r.frame
            if f.extended and not cfg.extended:
                continue        # the esd's 11-bit queues cannot carry it (5.1.5.1); the filter normally rejects it
            if len(self._received) >= self.rx_limit:
                self.rx_over_limit += 1
            self._received.append(RxFrame(f, r.time, r.seq))
            c.rx += 1
            _count_kind(c, "rx", f)
        sw = port.status_words(0)[self.channel]
        self._status_word = sw
        self._status_seen = True
        pressure = bool(sw & SW_RX_PRESSURE)
        if pressure and not self._pressure_seen:
            self._overflow_new = True
        self._pressure_seen = pressure

    # ------------------------------------------------------------------ Tx
    def queue(self, frames: Iterable[CanFrame]) -> list[int]:
        """Queue frames in order; their transaction numbers. FrameError (29-bit frame on the 11-bit
        queues, an FD frame) or TxQueueFull (beyond ``tx_limit``): nothing is queued."""
        _adapter, _port, book = self._require()
        with self._lock:
            return book.submit(frames)

    def send(self, frames: Iterable[CanFrame], timeout: float = DEFAULT_TIMEOUT) -> list[int]:
        """Queue ``frames`` and wait until every batch was accepted (exchanged with a full working counter)."""
        tns = self.queue(frames)
        if tns:
            book = self._require()[2]
            self._wait_for("Tx batch accepted", lambda: book.accepted(tns[-1]), timeout)
        return tns

    def accepted(self, tn: int) -> bool:
        """The RxPDO image carrying frame ``tn`` reached the ECAN-Lite."""
        book = self._require()[2]
        with self._lock:
            return book.accepted(tn)

    def completed(self, tn: int) -> bool:
        """Frame ``tn`` and every frame before it have their final TX_RESULT (chapter 10)."""
        book = self._require()[2]
        with self._lock:
            return book.completed(tn)

    def result(self, tn: int) -> TxResultCode | None:
        """The final TX_RESULT of a completed frame (0 OK; 2..5 not sent), None while it is not
        completed (not part of the esd API: the esd has no per-frame result)."""
        book = self._require()[2]
        with self._lock:
            return book.result(tn)

    def wait_sent(self, tn: int, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Wait until :meth:`completed`; MasterTimeout when not in time."""
        book = self._require()[2]
        book.completed(tn)
        self._wait_for(f"transaction {tn}", lambda: book.completed(tn), timeout)

    # ------------------------------------------------------------------ Rx
    def receive(self, timeout: float = 0.0, limit: int | None = None) -> list[RxFrame]:
        """The frames received so far, oldest first; with a timeout, waits for at least one. With
        ``status_pdo``, a rise of the status word's rx_pressure bit that came with new RX drops
        (0x902K:05) raises RxOverflowError once (its count: the drops since reset_statistics)."""
        self._require()
        with self._lock:
            overflow, self._overflow_new = self._overflow_new, False
        cfg = self.config
        if overflow and cfg is not None and cfg.status_pdo:
            lost = self._up(DIAG_BASE + self.channel, 5) - self._base_dropped
            if lost > self._reported_dropped:
                self._reported_dropped = lost
                raise RxOverflowError(f"the ECAN-Lite's RX cache of MCAN{self.channel} overran: {lost} frames lost "
                                      f"(0x{DIAG_BASE + self.channel:04X}:05)", lost)
        if timeout > 0:
            try:
                self._wait_for("receive", lambda: bool(self._received), timeout)
            except MasterTimeout:
                return []
        with self._lock:
            q = self._received
            n = len(q) if limit is None else min(limit, len(q))
            return [q.popleft() for _ in range(n)]

    # ------------------------------------------------------------------ status and statistics
    def status(self) -> CanStatus:
        """0x9000+K :01 ECR (TEC, REC; REC reads at least 128 when RP is set), :02 PSR (bus off,
        warning), and 'Rx overflow' = RX drops (0x9020+K:05) since :meth:`reset_statistics`."""
        k = self.channel
        ecr, psr = self._up(INFO_BASE + k, 1), self._up(INFO_BASE + k, 2)
        dropped = self._up(DIAG_BASE + k, 5) - self._base_dropped
        rec = (ecr >> 8) & 0x7F
        if ecr & ECR_RP:
            rec = max(rec, 128)
        bus_off = bool(psr & PSR_BO)
        return CanStatus(bus_off, bool(psr & PSR_EW) or bus_off, dropped > 0, rec, ecr & 0xFF)

    def pdo_status(self) -> CanStatus | None:
        """With ``status_pdo``: the last TxPDO header's channel status word (chapter 7) as a
        CanStatus -- bus_off (bit 5 / state 3), warning (bit 4 'warn'), rx_overflow (bit 6
        rx_pressure); the header has no error counters, they read 0. None without ``status_pdo`` or
        before the first cycle (as the esd's 0x1A85); LocalError when not started (as EsdHost)."""
        self._require()
        cfg = self.config
        if cfg is None or not cfg.status_pdo:
            return None
        with self._lock:
            if not self._status_seen:
                return None
            sw = self._status_word
        bus_off = bool(sw & SW_BUS_OFF) or sw & SW_STATE == STATE_BUSOFF
        return CanStatus(bus_off, bool(sw & SW_WARN) or bus_off, bool(sw & SW_RX_PRESSURE), 0, 0)

    def _cel(self) -> int:
        return (self._up(INFO_BASE + self.channel, 1) >> 16) & 0xFF

    def statistics(self) -> dict[str, int | None]:
        """The esd 0x2010 names (5.1.4.2): TX/RX frames from the host's counts (frames delivered,
        TX_RESULT OK by kind, failed TX_RESULTs as 'Aborted'), 'FIFO overrun' = 0x9020+K:05,
        'Error Frames' = ECR.CEL (saturates at 255), each since :meth:`reset_statistics`; the
        names in :data:`NO_SOURCE` are None."""
        c = self._counts
        k = self.channel
        values: dict[int, int | None] = {
            0x30: c.tx_requested, 0x31: c.tx_ok, 0x32: c.rx,
            0x35: self._up(DIAG_BASE + k, 5) - self._base_dropped, 0x36: max(0, self._cel() - self._base_cel),
            0x37: c.tx_failed, 0x38: c.rx_std, 0x39: c.rx_std_rtr, 0x3A: c.rx_ext, 0x3B: c.rx_ext_rtr,
            0x3C: c.tx_std, 0x3D: c.tx_std_rtr, 0x3E: c.tx_ext, 0x3F: c.tx_ext_rtr}
        return {name: values.get(sub) for sub, name in STATISTICS.items()}

    def reset_statistics(self) -> None:
        """The host's counts to zero and the 0x9020+K:05 / ECR.CEL baselines taken now (the
        ECAN-Lite's counters themselves, shared with the other channels' users, stay)."""
        with self._lock:
            self._counts = _Counts()
        self._base_dropped = self._up(DIAG_BASE + self.channel, 5)
        self._base_cel = self._cel()
        self._reported_dropped = 0

    def read_filters(self) -> tuple[FilterArea, ...]:
        """The channel's range filters read through the editing window (13.4 :43/:44 index, :45/:46
        = 1 read): standard entries first, then extended (merged areas as the translator wrote them)."""
        base = CONFIG_BASE + self.channel
        areas: list[FilterArea] = []
        for extended, count_sub, idx_sub, cmd_sub, first in ((False, 49, 43, 45, 50), (True, 55, 44, 46, 56)):
            for i in range(self._up(base, count_sub)):
                self._down(base, idx_sub, i, 1)
                self._down(base, cmd_sub, 1, 1)
                if self._up(base, first) == 0:               # type 0: range
                    areas.append(FilterArea(self._up(base, first + 3), self._up(base, first + 4), extended))
        return tuple(areas)

    def read_bitrate(self) -> tuple[int, int]:
        """(0xF800:02, 0xF800:05) the channel's setting stands for: the configured pair when
        0x800x:19 / :08 hold what it translates to, else the plain choice for the rate read
        (:func:`for_bitrate`); (FFh, NTCAN_NO_BAUDRATE) when the channel is off the PDO."""
        base = CONFIG_BASE + self.channel
        if not self._up(0x8010, 4) >> self.channel & 1:
            return 0xFF, NTCAN_NO_BAUDRATE
        rate, listen = self._up(base, 19), self._up(base, 8) == 3
        cfg, tr = self.config, self.translation
        if cfg is not None and tr is not None and (tr.bitrate, tr.listen_only) == (rate, listen):
            return cfg.bitrate.index, cfg.bitrate.api
        chosen = for_bitrate(rate, listen)
        return chosen.index, chosen.api



if TYPE_CHECKING:
    from gatewaylab.hosts.esd_can_ethercat import EsdHost, EsdQueueApi

    def _both_satisfy_the_contract(ecan: EsdQueueOnEcanLite, esd: EsdHost) -> tuple[EsdQueueApi, EsdQueueApi]:
        """mypy --strict checks both classes against the Protocol here (the tests check it at run time)."""
        return ecan, esd
