"""One MCAN channel (manual 13.4, chapter 7): a bus controller programmed from the applied
configuration, the filter lists being edited, the data path between bus and PDOs, and the
chapter-7 status word. Sans-I/O: the bus calls in on the injected clock; nothing sleeps.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from types import MappingProxyType

from gatewaylab.bus.controller import (
    BusEvent,
    Controller,
    ErrorFrameEvent,
    ErrorState,
    StateChangeEvent,
    TxAbortedEvent,
    TxDoneEvent,
)
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.ecanlite.mcan import registers
from gatewaylab.devices.ecanlite.mcan.datapath import (
    ChannelCounters,
    DataPath,
    DataPathPolicy,
    Degraded,
    EventFlag,
    ReceivedFrame,
    TxEntry,
)
from gatewaylab.devices.ecanlite.mcan.filters import EMPTY_FILTER, FilterElement, accept
from gatewaylab.devices.ecanlite.mcan.layout import (
    ApplyStatus,
    BuildError,
    ChannelRuntime,
    ChannelSettings,
    NodeMode,
    build,
)
from gatewaylab.devices.ecanlite.mcan.objects import EXT_LIST_MAX, STD_LIST_MAX
from gatewaylab.devices.ecanlite.mcan.registers import IR_BO, IR_EP, IR_HPM, IR_PEA, IR_TC, LEC
from gatewaylab.devices.ecanlite.stream import TxResultCode

__all__ = ["ChannelState", "McanChannel"]


class ChannelState(enum.IntEnum):
    """Chapter 7 status word bits 0..2."""

    DISABLED = 0
    INIT = 1
    RUN = 2
    BUSOFF = 3
    ERROR = 4
    LISTEN = 5


class McanChannel:
    """One MCAN channel: controller configuration, filters, data path (RX cache, TX ring), status."""

    def __init__(self, index: int, clock: Clock, controller: Controller | None) -> None:
        """Channel ``index`` on ``controller`` (None: no CAN pins wired, the channel is disabled)."""
        self.index = index
        self.clock = clock
        self.controller = controller
        self.runtime: ChannelRuntime | None = None
        #: The requested filter lists as edited through the window (applied at the next apply).
        self.std_filters: list[FilterElement] = [EMPTY_FILTER] * STD_LIST_MAX
        self.ext_filters: list[FilterElement] = [EMPTY_FILTER] * EXT_LIST_MAX
        self.path = DataPath(clock, self.on_frame)
        #: HPMS (high priority message status) and PSR.LEC as the last frame / error left them.
        self.hpms = 0
        self.lec = 0
        #: Whitelisted registers without a model (interrupt routing, acknowledges): read back.
        self.expert: dict[int, int] = {}
        #: 0x8030 fine bypass (13.2.3): TxPDO bit 2 MCAN_READ, RxPDO bit 4 TX_RING / bit 5 MCAN_WRITE.
        self.bypass_read = False
        self.bypass_write = False
        if controller is not None:
            controller.on_frame = self.on_frame
            controller.on_event = self.on_event

    def __repr__(self) -> str:
        return f"<McanChannel {self.index} {ChannelState(self.status_word() & 7).name}>"

    # -- contract properties ---------------------------------------------------------------------
    @property
    def enabled(self) -> bool:
        """A controller is attached (an unconnected channel is disabled) and a config is applied."""
        return self.controller is not None and self.runtime is not None

    @property
    def fd(self) -> bool:
        """The applied configuration is CAN FD."""
        return self.runtime is not None and self.runtime.fd

    @property
    def classic(self) -> bool:
        """The applied configuration is classic CAN."""
        return not self.fd

    @property
    def policy(self) -> DataPathPolicy:
        """The applied data-path policy (0x802x)."""
        return self.path.policy

    @property
    def counters(self) -> ChannelCounters:
        """The 0x9000 / 0x9020 counters."""
        return self.path.counters

    # -- configuration ---------------------------------------------------------------------------
    def apply(self, settings: ChannelSettings) -> ApplyStatus:
        """Apply a configuration (0x800x:01 = 1): the old one stays when this one fails."""
        try:
            runtime = build(settings)
        except BuildError as exc:
            self.counters.last_error = int(exc.status)
            return exc.status
        try:
            self.activate(runtime)
        except GatewaylabError:
            self.counters.last_error = int(ApplyStatus.RUNTIME_FAIL)
            if self.runtime is not None:
                self.activate(self.runtime)
            return ApplyStatus.RUNTIME_FAIL
        self.runtime = runtime
        self.path.degraded &= ~Degraded.BUS_OFF
        return ApplyStatus.OK

    def activate(self, rt: ChannelRuntime) -> None:
        """Program the controller: re-time it, FD, node mode, retransmission; a restart of the
        MCAN also ends bus-off (host recovery)."""
        c = self.controller
        if c is None:
            return
        bus = c.bus
        c.fd = rt.fd
        c.bitrate = rt.nominal_bitrate
        c.data_bitrate = rt.data_bitrate if rt.fd else None
        c.auto_retransmit = rt.auto_retransmit
        c.listen_only = rt.node_mode is NodeMode.LISTEN
        if rt.node_mode is NodeMode.INTERNAL_LOOPBACK:
            if c.connected:
                bus.disconnect(c)
        elif not c.connected and c in bus.controllers:
            bus.reconnect(c)
        self._apply_recovery()
        if c.state is ErrorState.BUS_OFF:
            c.recover()

    def release(self) -> None:
        """Let go of the controller (pin rotation, reset): queued frames not on the wire are taken
        back and reported as aborted (ResultCode 2), the callbacks unhooked."""
        c = self.controller
        if c is None:
            return
        self.path.withdraw_all(c)
        self.unhook()
        self.controller = None

    def unhook(self) -> None:
        """The controller forgets this channel's callbacks (release, firmware stop)."""
        c = self.controller
        if c is not None:
            if c.on_frame == self.on_frame:
                c.on_frame = None
            if c.on_event == self.on_event:
                c.on_event = None

    def bind(self, controller: Controller | None) -> None:
        """Take a controller (pin rotation): hook it and program the applied configuration."""
        self.controller = controller
        if controller is not None:
            controller.on_frame = self.on_frame
            controller.on_event = self.on_event
            if self.runtime is not None:
                self.activate(self.runtime)

    def apply_policy(self, policy: DataPathPolicy) -> None:
        """Apply a data-path policy (0x802x:02 = 1); also ends a degraded state and host recovery."""
        self.path.apply_policy(policy)
        self._apply_recovery()
        c = self.controller
        if c is not None and c.state is ErrorState.BUS_OFF:
            c.recover()

    def _apply_recovery(self) -> None:
        c = self.controller
        if c is not None:
            p = self.path.policy
            c.auto_recover = (not p.enable) or p.busoff_recovery in (1, 3)

    def filters(self, extended: bool) -> list[FilterElement]:
        """The requested filter list being edited."""
        return self.ext_filters if extended else self.std_filters

    def settings_from(self, values: Mapping[int, int]) -> ChannelSettings:
        """Requested settings: ``values`` (0x800x) and the edited filter lists."""
        return ChannelSettings(MappingProxyType(dict(values)), tuple(self.std_filters), tuple(self.ext_filters))

    # -- bus side --------------------------------------------------------------------------------
    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A frame received from the bus (or looped back): acceptance filtering, then the data path."""
        self.lec = 0
        rt = self.runtime
        if rt is None:
            return
        store, hpms = accept(rt, frame)
        if hpms >= 0:
            self.hpms = hpms
            self.path.ir |= IR_HPM
        if store >= 0:
            self.path.receive(frame, t, store, rt)

    def on_event(self, ev: BusEvent) -> None:
        """A bus event of the controller: transmission results, error frames, state changes."""
        path = self.path
        if isinstance(ev, TxDoneEvent):
            self.lec = 0
            path.ir |= IR_TC
            path.finish(ev.frame, TxResultCode.OK)
        elif isinstance(ev, TxAbortedEvent):
            path.finish(ev.frame, TxResultCode.BUS_OFF if ev.reason == "bus-off" else TxResultCode.BUS_BUSY)
        elif isinstance(ev, ErrorFrameEvent):
            self.lec = LEC.get(ev.kind, 7)
            path.counters.error_log = min(255, path.counters.error_log + 1)
            path.ir |= IR_PEA
        elif isinstance(ev, StateChangeEvent):
            self._state_changed(ev)

    def _state_changed(self, ev: StateChangeEvent) -> None:
        path = self.path
        path.latch(EventFlag.STATE_CHANGE)
        if ev.new is ErrorState.ERROR_PASSIVE:
            path.ir |= IR_EP
            path.latch(EventFlag.WARNING)
        elif ev.new is ErrorState.BUS_OFF:
            path.ir |= IR_BO
            path.latch(EventFlag.BUS_OFF)
            c = path.counters
            c.bus_off += 1
            p = path.policy
            policy = p.busoff_recovery if p.enable else 1
            if policy in (1, 2, 3):
                c.recovery_attempts = min(0xFFFF, c.recovery_attempts + 1)
            if policy == 2 and self.controller is not None:
                self.clock.call_soon(self.controller.recover)
            if policy == 3:
                path.degraded |= Degraded.BUS_OFF

    # -- PDO side --------------------------------------------------------------------------------
    def drain_budget(self) -> int:
        """Frames one TxPDO build may take from the RX cache (0x802x:04..06)."""
        return self.path.drain_budget()

    def peek(self, limit: int) -> Sequence[ReceivedFrame]:
        """The oldest received frames, at most ``limit`` and the drain budget (not removed);
        none while the 0x8030 MCAN_READ bypass is on."""
        return () if self.bypass_read else self.path.peek(limit)

    def consume(self, n: int) -> None:
        """Remove the ``n`` oldest frames (they went into a TxPDO)."""
        self.path.consume(n)

    def pending_rx(self) -> int:
        """Frames waiting in the RX cache."""
        return len(self.path.rx)

    def pending_tx(self) -> int:
        """Frames handed to the channel and not finished (in the TX ring or the MCAN)."""
        return self.path.pending_tx()

    def submit(self, frame: CanFrame, ref: object = None) -> int:
        """Queue a frame for transmission: 0 = queued (its result comes from
        :meth:`take_tx_results`), else the TxResultCode to report at once."""
        c = self.controller
        rt = self.runtime
        if c is None or rt is None or rt.node_mode in (NodeMode.LISTEN, NodeMode.RESTRICTED):
            return TxResultCode.INVALID_CHANNEL
        if frame.fd and not rt.fd:
            return TxResultCode.INVALID_CHANNEL
        if self.bypass_write:
            self.path.results.append((ref, TxResultCode.OK))     # 0x8030 TX_RING / MCAN_WRITE bypass
            return TxResultCode.OK
        if c.state is ErrorState.BUS_OFF:
            return TxResultCode.BUS_OFF
        return self.path.offer(TxEntry(frame, ref), c, rt)

    def take_tx_results(self) -> list[tuple[object, int]]:
        """Refs of frames finished since the last call, with their TxResultCode."""
        path = self.path
        out, path.results = path.results, []
        return out

    def on_cycle(self, t: float) -> None:
        """Per-cycle tick: a new TX budget (0x802x:12) serves the firmware TX ring; TX backoff
        counts down."""
        self.path.serve_ring(self.controller, self.runtime)

    # -- status ----------------------------------------------------------------------------------
    def state(self) -> ChannelState:
        """Chapter 7 state field."""
        c = self.controller
        rt = self.runtime
        if c is None:
            return ChannelState.DISABLED
        if rt is None:
            return ChannelState.INIT
        if c.state is ErrorState.BUS_OFF:
            return ChannelState.BUSOFF
        if rt.node_mode in (NodeMode.LISTEN, NodeMode.RESTRICTED):
            return ChannelState.LISTEN
        if c.state is ErrorState.ERROR_PASSIVE:
            return ChannelState.ERROR
        return ChannelState.RUN

    def _status(self) -> int:
        c = self.controller
        path = self.path
        word = int(self.state())
        if self.fd:
            word |= 1 << 3
        if path.degraded or (c is not None and (c.state is not ErrorState.ERROR_ACTIVE
                                                 or c.tec >= 96 or c.rec >= 96)):
            word |= 1 << 4
        if c is not None and c.state is ErrorState.BUS_OFF:
            word |= 1 << 5
        rxp, txp = len(path.rx), path.pending_tx()
        if path.rx_recent_drop or 4 * rxp >= 3 * path.depth:
            word |= 1 << 6
        rt = self.runtime
        tx_cap = rt.tx_elements if rt is not None else 32
        if path.tx_recent_full or path.backoff_cycles or 4 * txp >= 3 * tx_cap:
            word |= 1 << 7
        if path.detail_pending:
            word |= 1 << 8
        if rxp > 7 or txp > 7:
            word |= 1 << 9
        return word | min(rxp, 7) << 10 | min(txp, 7) << 13

    def status_word(self) -> int:
        """The chapter-7 16-bit status word for this cycle's header (the 'recent overflow'
        pressure bits are reported once, then cleared)."""
        word = self._status()
        self.path.rx_recent_drop = self.path.tx_recent_full = False
        return word

    # -- registers and details (0x9000, 0x9020, 0xA000) --------------------------------------------
    def register(self, offset: int) -> int:
        """Read an MCAN register of this channel (:func:`.registers.read_register`)."""
        return registers.read_register(self, offset)

    def write_register(self, offset: int, value: int) -> bool:
        """A whitelisted write (13.6, :func:`.registers.write_register`); False = refused (status 2)."""
        return registers.write_register(self, offset, value)

    def info(self) -> dict[int, int]:
        """0x900x values by subindex (13.5)."""
        c = self.counters
        reg = self.register
        return {1: reg(0x0040), 2: reg(0x0044), 3: reg(0x0050), 4: reg(0x00A4), 5: reg(0x00B4), 6: reg(0x00C4),
                7: 0, 8: reg(0x0094), 9: self._status(),
                10: min(len(self.path.rx), 0xFFFF), 11: min(self.pending_tx(), 0xFFFF), 12: int(self.path.events),
                13: c.rx_dropped_total, 14: c.tx_fifo_full, 15: c.bus_off, 16: c.detail_sequence}

    def take_events(self) -> int:
        """Read and clear the latched event flags (0x900x:12) and the detail_pending bit."""
        path = self.path
        flags, path.events = int(path.events), EventFlag(0)
        path.detail_pending = False
        return flags

    def diagnostics(self) -> dict[int, int]:
        """0x902x values by subindex (13.2.5)."""
        c = self.counters
        return {1: len(self.path.rx), 2: c.rx_high_watermark, 3: c.rx_drain_last, 4: c.rx_drain_max,
                5: c.rx_dropped_total, 6: c.rx_dropped_old, 7: c.rx_dropped_new, 8: c.rx_dropped_critical,
                9: c.consumed_last, 10: c.consumed_max, 11: c.tx_fifo_full, 12: c.tx_stale_dropped,
                13: c.bus_off, 14: c.recovery_attempts, 15: int(self.path.degraded), 16: c.last_error,
                17: 0, 18: 0, 19: 0, 20: 0}

    def clear_diagnostics(self) -> None:
        """0xB000 bit 5: counters, latched flags and the degraded state back to zero."""
        self.path.clear_diagnostics()
