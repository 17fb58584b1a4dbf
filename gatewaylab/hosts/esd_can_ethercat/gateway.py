"""One esd CAN-EtherCAT seen from the master: configuration in PREOP, the counter handshake every
cycle, status and statistics (manual 4.2, 5.1.3-5.1.5; shared note 'esd-mdp5000-queues').

:class:`EsdHost` works on any :class:`~gatewaylab.hosts.ethercat.backend.MasterBackend` (the in-process
master or SOEM on a NIC) and one slave position. The bytes are the codec's
(:mod:`..codec`), the handshake is the sans-I/O :class:`~.handshake.Handshake`; this class adds
the SDO traffic and the waiting, which goes through ``backend.clock.wait`` only.

Cycle driving: the application calls :meth:`EsdHost.cycle` once per process-data cycle (outputs,
``backend.exchange()``, working counter, inputs), or :meth:`EsdHost.before_exchange` /
:meth:`EsdHost.after_exchange` around its own exchange when one master serves several gateways.
The blocking calls (:meth:`send`, :meth:`wait_sent`, :meth:`receive` with a timeout) run the
cycles themselves, unless ``external_cycle`` says another thread does.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError, LocalError, ProtocolError
from gatewaylab.devices.esd_can_ethercat.codec import CanStatus
from gatewaylab.devices.esd_can_ethercat.objects import PRODUCT_CODE, STATISTICS, VENDOR_ID
from gatewaylab.ethercat.errors import AlStatusError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.esd_can_ethercat.config import BitRate, EsdConfig, FilterArea, QueueLayout
from gatewaylab.hosts.esd_can_ethercat.handshake import (
    DEFAULT_RX_LIMIT,
    DEFAULT_TX_LIMIT,
    Handshake,
    RxFrame,
    RxOverflowError,
)
from gatewaylab.hosts.esd_can_ethercat.loop import DEFAULT_TIMEOUT, HostLoop
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout
from gatewaylab.hosts.ethercat.states import walk_to

__all__ = ["MAP_ATTEMPTS", "SDO_ATTEMPTS", "SDO_RETRY_WAIT", "SM_CONFIG_CODES", "EsdHost", "ReadbackError"]


#: DEFAULT_TIMEOUT (5 s: a full local Tx queue of 1000 frames at 125 kbit/s takes about a second to
#: drain), WKC_RECOVER and STATE_CHECK_PERIOD live in loop.py with the waiting they govern.
#: 0x8000 subindexes (5.1.5.5).
FLAGS, RX_QUEUE, TX_QUEUE, LOCAL_RX, LOCAL_TX = 0x20, 0x21, 0x22, 0x23, 0x24
#: 0x2010 subindexes of type UINT8 (5.1.4.2 'App. CPU Usage'); the others are UINT32.
_U8_STATISTICS = (0x20, 0x21)
_FMT = {1: "<B", 2: "<H", 4: "<I", 8: "<Q"}
#: Tries of one SDO service that timed out (the readback decides whether a download arrived), and
#: the seconds waited before the n-th repetition (n x this): a late answer is flushed meanwhile.
SDO_ATTEMPTS = 8
SDO_RETRY_WAIT = 0.1
#: An SDO service that got no answer, or a late answer to an earlier request (SOEM's 'unexpected
#: frame returned', a ProtocolError): repeated, as its outcome is unknown.
_RETRYABLE = (MasterTimeout, ProtocolError)
#: config_map runs before the mapped sizes agree with the mapping objects read back.
MAP_ATTEMPTS = 3
#: AL status codes of a SyncManager set up differently from the mapping (ETG.1000.6: 0x001D invalid
#: output configuration, 0x001E invalid input configuration): mapping again may cure them.
SM_CONFIG_CODES = (0x001D, 0x001E)


class ReadbackError(ConfigError):
    """A value written in PREOP reads back different (the gateway kept another value)."""

    def __init__(self, index: int, subindex: int, wrote: int, read: int) -> None:
        super().__init__(f"0x{index:04X}:{subindex:02X} written 0x{wrote:X}, reads back 0x{read:X}")
        self.index, self.subindex, self.wrote, self.read = index, subindex, wrote, read


class EsdHost(HostLoop):
    """The counter handshake of one esd CAN-EtherCAT at ``position`` on ``backend``."""

    def __init__(self, backend: MasterBackend, position: int = 0, *, cycle_time: float = 0.001,
                 external_cycle: bool = False, check_identity: bool = True,
                 tx_limit: int = DEFAULT_TX_LIMIT, rx_limit: int = DEFAULT_RX_LIMIT) -> None:
        super().__init__(backend, position, cycle_time, external_cycle)
        self.tx_limit = tx_limit
        self.rx_limit = rx_limit
        self.config: EsdConfig | None = None
        self.layout: QueueLayout | None = None
        self.handshake: Handshake | None = None
        #: SDO services repeated after a timeout.
        self.sdo_retries = 0
        #: config_map calls repeated because the mapped sizes differed from the mapping read back.
        self.map_retries = 0
        if check_identity:
            ident = next((s for s in backend.slaves() if s.position == position), None)
            if ident is None:
                raise ConfigError(f"no slave at position {position}")
            if (ident.vendor_id, ident.product_code) != (VENDOR_ID, PRODUCT_CODE):
                raise ConfigError(f"slave {position} is vendor 0x{ident.vendor_id:X} product 0x{ident.product_code:X}, "
                                  f"not an esd CAN-EtherCAT (0x{VENDOR_ID:X}/0x{PRODUCT_CODE:X}, manual 5.1.3.5)")

    # ------------------------------------------------------------------ SDO helpers
    def _upload(self, index: int, sub: int) -> int:
        """An SDO upload as an unsigned integer; repeated after a timeout or a late answer (reads are idempotent)."""
        for attempt in range(SDO_ATTEMPTS):
            try:
                raw = self.backend.sdo_upload(self.position, index, sub)
                break
            except _RETRYABLE:
                if attempt == SDO_ATTEMPTS - 1:
                    raise
                self._retry_wait(attempt)
        return int.from_bytes(raw, "little")

    def _retry_wait(self, attempt: int) -> None:
        self.sdo_retries += 1
        self.clock.wait(SDO_RETRY_WAIT * (attempt + 1))

    def _download(self, index: int, sub: int, value: int, size: int) -> None:
        self.backend.sdo_download(self.position, index, sub, struct.pack(_FMT[size], value))

    def _write(self, index: int, sub: int, value: int, size: int) -> None:
        """Download, then upload and compare (a readback check as IgH's startup SDOs do). A download
        without an answer in time is judged by the readback: a gateway that takes long to apply a
        value (0x8000 rebuilds the mapping) may have taken it while the master's frame timed out."""
        for attempt in range(SDO_ATTEMPTS):
            try:
                self._download(index, sub, value, size)
                break
            except _RETRYABLE:
                if attempt == SDO_ATTEMPTS - 1:
                    raise
                self._retry_wait(attempt)
                if self._upload(index, sub) == value:
                    return
        got = self._upload(index, sub)
        if got != value:
            raise ReadbackError(index, sub, value, got)

    # ------------------------------------------------------------------ configuration (PREOP)
    def to_preop(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Bring the slave to PREOP (from BOOT through INIT); the handshake stops until :meth:`attach`."""
        with self._lock:
            self.handshake = None
        walk_to(self.backend, self.position, AlState.PREOP, timeout)

    def configure(self, config: EsdConfig | None = None, /, **changes: Any) -> QueueLayout:
        """Write ``config`` (or EsdConfig(**changes)) in PREOP with readback checks, then read the
        mapping back (0x1C12/0x1C13, 0x1600, 0x1A00, 0x1A85) and return the queue layout.

        Order: 0xF800 (:05 before :02 = FFh, or :02 = Table 6 index), 0x8000 (queue sizes before
        the 29-bit flag when switching to 29 bit, after it when switching back: the gateway
        refuses sizes the mode cannot hold), 0x8001 (:00 = 0, the areas, :00 = n), 0x1C12, 0x1C13.
        SdoAbort (with the gateway's abort code) or ReadbackError on the first refusal."""
        cfg = replace(config, **changes) if config is not None else EsdConfig(**changes)
        self.to_preop()
        self.set_bitrate(cfg.bitrate)
        sizes = ((RX_QUEUE, cfg.rx_queue, 1), (TX_QUEUE, cfg.tx_queue, 1), (LOCAL_RX, cfg.local_rx_queue, 2),
                 (LOCAL_TX, cfg.local_tx_queue, 2))
        if not cfg.extended:
            self._write(0x8000, FLAGS, cfg.flags, 2)
        for sub, value, size in sizes:
            self._write(0x8000, sub, value, size)
        if cfg.extended:
            self._write(0x8000, FLAGS, cfg.flags, 2)
        self._write(0x8001, 0, 0, 1)
        for i, area in enumerate(cfg.filters, start=1):
            self._write(0x8001, i, area.value, 8)
        if cfg.filters:
            self._write(0x8001, 0, len(cfg.filters), 1)
        self._assign(0x1C12, (0x1600,))
        self._assign(0x1C13, (0x1A00, 0x1A85) if cfg.status_pdo else (0x1A00,))
        layout = self.read_layout()
        if (layout.extended, layout.tx_messages, layout.rx_messages, layout.status_pdo) != (
                cfg.extended, cfg.tx_queue, cfg.rx_queue, cfg.status_pdo):
            raise ConfigError(f"the mapping does not follow 0x8000: {layout}")
        self.config, self.layout = cfg, layout
        return layout

    def set_bitrate(self, bitrate: BitRate) -> None:
        """Write 0xF800 with readback: :05 'API-baud rate' first, then :02 = FFh; or :02 = the
        Table 6 index (5.1.5.9: an index other than FFh wins over :05). The manual restricts
        0xF800 to no state (only 0x8000, 0x7000 and 0x2000:01 carry the PREOP-only NOTICE), so
        this works in OP too, without remapping."""
        if bitrate.index == 0xFF:
            self._write(0xF800, 5, bitrate.api, 4)
        self._write(0xF800, 2, bitrate.index, 1)
        if self.config is not None:
            self.config = replace(self.config, bitrate=bitrate)

    def _assign(self, index: int, pdos: tuple[int, ...]) -> None:
        self._write(index, 0, 0, 1)
        for i, pdo in enumerate(pdos, start=1):
            self._write(index, i, pdo, 2)
        self._write(index, 0, len(pdos), 1)

    def read_layout(self) -> QueueLayout:
        """The process image the mapping describes: 0x1C12/0x1C13 and each assigned PDO's entries
        (5.1.3.7-5.1.3.11), as a master reads them before mapping."""
        outputs = self._assigned(0x1C12)
        inputs = self._assigned(0x1C13)
        if not outputs or outputs[0] != 0x1600 or not inputs or inputs[0] != 0x1A00:
            raise ConfigError(f"0x1C12 {outputs} / 0x1C13 {inputs}: 0x1600 and 0x1A00 must come first "
                              "(manual 5.1.3.7, 5.1.3.8)")
        out_entries = self._mapping(0x1600)
        in_entries = [e for pdo in inputs for e in self._mapping(pdo)]
        extended = out_entries[0] >> 16 == 0x7001
        n_1a00 = self._upload(0x1A00, 0)
        return QueueLayout(extended=extended, tx_messages=len(out_entries) - 3, rx_messages=n_1a00 - 4,
                           status_pdo=0x1A85 in inputs[1:],
                           output_bytes=sum(e & 0xFF for e in out_entries) // 8,
                           input_bytes=sum(e & 0xFF for e in in_entries) // 8)

    def _assigned(self, index: int) -> list[int]:
        return [self._upload(index, i) for i in range(1, self._upload(index, 0) + 1)]

    def _mapping(self, pdo: int) -> list[int]:
        return [self._upload(pdo, i) for i in range(1, self._upload(pdo, 0) + 1)]

    # ------------------------------------------------------------------ start / stop
    def start(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Map the segment (``backend.config_map()``), SAFEOP, OP and :meth:`attach`: the whole
        start-up for a script with this one gateway (4.2: mapping read after configuring)."""
        if self.layout is None:
            raise LocalError("configure() first")
        for attempt in range(MAP_ATTEMPTS):
            self.backend.config_map()
            try:
                self._check_sizes()
                self.backend.request_state(AlState.SAFEOP, self.position, timeout)
                break
            except (ConfigError, AlStatusError) as exc:
                if attempt == MAP_ATTEMPTS - 1 or (isinstance(exc, AlStatusError) and exc.code not in SM_CONFIG_CODES):
                    raise
                # the master's mapping read lost an SDO answer, or a SyncManager write got lost:
                # back to PREOP (acknowledging the error) and map again
                self.map_retries += 1
                self.backend.request_state(AlState.PREOP, self.position, timeout)
        self.backend.request_state(AlState.OP, self.position, timeout)
        self.attach()

    def _check_sizes(self) -> None:
        layout = self.layout
        assert layout is not None
        out_n, in_n = len(self.backend.outputs(self.position)), len(self.backend.inputs(self.position))
        if (out_n, in_n) != (layout.output_bytes, layout.input_bytes):
            raise ConfigError(f"mapped {out_n} B outputs / {in_n} B inputs, the mapping objects give "
                              f"{layout.output_bytes} / {layout.input_bytes}")

    def attach(self) -> None:
        """Start the handshake on the mapped image (after the application's config_map and its
        PREOP -> SAFEOP, which resets the gateway's counters): counters from the outputs."""
        if self.layout is None:
            self.layout = self.read_layout()
        self._check_sizes()
        out = self.backend.outputs(self.position)
        tx, rx = struct.unpack_from("<HH", out, 0)
        with self._lock:
            self.handshake = Handshake(self.layout, tx_counter=tx, rx_counter=rx, tx_limit=self.tx_limit,
                                       rx_limit=self.rx_limit)

    def stop(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Back to PREOP: the gateway stops taking batches; queued frames stay unsent."""
        self.to_preop(timeout)

    def _hs(self) -> Handshake:
        hs = self.handshake
        if hs is None:
            raise LocalError("the handshake is not running: configure(), then start() or attach()")
        return hs

    # ------------------------------------------------------------------ the cycle
    def before_exchange(self) -> None:
        """Write the outputs for the next exchange (a new Tx batch, the Rx acknowledgement)."""
        with self._lock:
            hs = self.handshake
            if hs is not None:
                hs.write_outputs(self.backend.outputs(self.position))

    def after_exchange(self, wkc: int, expected: int) -> bool:
        """Read the inputs of the exchange just made; a wrong working counter leaves them unused
        (counted in ``wkc_errors``: the outputs stay, so the next cycle repeats them)."""
        self.cycles += 1
        if wkc != expected:
            self.wkc_errors += 1
            self._bad_cycles += 1
            return False
        self._bad_cycles = 0
        with self._lock:
            hs = self.handshake
            if hs is not None:
                hs.read_inputs(self.backend.inputs(self.position), self.clock.now())
        return True

    def cycle(self) -> bool:
        """One process-data cycle: outputs, ``backend.exchange()``, working counter, inputs.
        Returns False when the working counter was wrong."""
        self._hs()
        self.before_exchange()
        wkc, expected = self.backend.exchange()
        return self.after_exchange(wkc, expected)

    # ------------------------------------------------------------------ Tx
    def queue(self, frames: Iterable[CanFrame]) -> list[int]:
        """Queue frames for the next batches without waiting; returns their transaction numbers."""
        with self._lock:
            return self._hs().submit(frames)

    def send(self, frames: Iterable[CanFrame], timeout: float = DEFAULT_TIMEOUT) -> list[int]:
        """Queue ``frames`` and wait until the gateway copied all of them (the Tx counter came back
        for each batch of up to 0x8000:22 frames, in order, 5.1.5.3); returns their transaction
        numbers (see :meth:`completed` / :meth:`wait_sent` for 'sent on CAN')."""
        tns = self.queue(frames)
        if tns:
            hs = self._hs()
            self._wait_for("Tx counter handshake", lambda: hs.accepted(tns[-1]), timeout)
        return tns

    def accepted(self, tn: int) -> bool:
        """The gateway copied frame ``tn`` into its local Tx queue."""
        with self._lock:
            return self._hs().accepted(tn)

    def completed(self, tn: int) -> bool:
        """Frame ``tn`` is done: the input Tx Transaction Number reached it or a later frame."""
        with self._lock:
            return self._hs().completed(tn)

    def wait_sent(self, tn: int, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Wait until :meth:`completed` (the input Tx Transaction Number, 5.1.5.1 'Contains the
        transaction number of the last sent Tx'); MasterTimeout (a TimeoutError) when not in time."""
        hs = self._hs()
        self._wait_for(f"transaction {tn}", lambda: hs.completed(tn), timeout)

    # ------------------------------------------------------------------ Rx
    def receive(self, timeout: float = 0.0, limit: int | None = None) -> list[RxFrame]:
        """The frames received so far (each Rx batch was acknowledged once read, 5.1.5.1); with a
        timeout, waits for at least one (an empty list when none came). With the 0x1A85 status PDO
        assigned, a rise of its 'Rx overflow' bit raises RxOverflowError once (count from
        0x2010:35); the frames stay for the next call."""
        hs = self._hs()
        with self._lock:
            overflow = hs.overflow_reported()
        if overflow:
            lost = self._upload(0x2010, 0x35)
            raise RxOverflowError(f"the gateway's local Rx queue overran: {lost} frames lost "
                                  "(0xF108:03, 0x2010:35)", lost)
        if timeout > 0:
            try:
                self._wait_for("receive", lambda: hs.buffered > 0, timeout)
            except MasterTimeout:
                return []
        with self._lock:
            return hs.take_received(limit)

    # ------------------------------------------------------------------ status and statistics
    def status(self) -> CanStatus:
        """0xF108 'CAN Status' by SDO (5.1.5.8): bus off, warning limit, Rx overflow, REC, TEC."""
        return CanStatus(bool(self._upload(0xF108, 1)), bool(self._upload(0xF108, 2)),
                         bool(self._upload(0xF108, 3)), self._upload(0xF108, 0x21), self._upload(0xF108, 0x22))

    def pdo_status(self) -> CanStatus | None:
        """0xF108 as the last cycle's 0x1A85 PDO brought it (None without the status PDO)."""
        with self._lock:
            return self._hs().status

    def statistics(self) -> dict[str, int]:
        """0x2010 'Statistics' by SDO, every subindex by its manual name (5.1.4.2)."""
        return {name: self._upload(0x2010, sub) for sub, name in STATISTICS.items()}

    def reset_statistics(self) -> None:
        """Write 0x2010:01 'Reset' (5.1.4.2: 'When this object is written the statistics are reset')."""
        self._download(0x2010, 1, 0, 4)

    def read_filters(self) -> tuple[FilterArea, ...]:
        """0x8001 as the gateway holds it."""
        return tuple(FilterArea.from_value(self._upload(0x8001, i)) for i in range(1, self._upload(0x8001, 0) + 1))

    def read_bitrate(self) -> tuple[int, int]:
        """(0xF800:02 'Baud rate', 0xF800:05 'API-baud rate')."""
        return self._upload(0xF800, 2), self._upload(0xF800, 5)
