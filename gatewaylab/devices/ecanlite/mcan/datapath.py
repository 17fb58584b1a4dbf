"""The MCAN channel's firmware data path (manual 13.2.2, 13.5): between the MCAN and the PDOs.

:class:`DataPathPolicy` is an applied 0x802x policy. :class:`DataPath` is what it governs: the
firmware RX cache fed by the Message RAM stores (RX FIFO0, RX FIFO1, RX buffers, each with its
blocking or overwrite mode), drained by budgets into the TxPDO; the MCAN TX FIFO/queue and the
firmware TX ring in front of it, served by a per-cycle TX budget; and the bookkeeping of both
directions (drop and refusal counters, pressure flags, latched events, the degraded state) in one
place. The channel (:mod:`.channel`) feeds it bus frames and events; it never sleeps.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

from gatewaylab.bus.controller import Controller, ErrorState
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.devices.ecanlite.mcan.filters import RX_STORES
from gatewaylab.devices.ecanlite.mcan.layout import TX_PAD, ChannelRuntime, NodeMode
from gatewaylab.devices.ecanlite.mcan.objects import POLICY_DEFAULTS, RX_CACHE_MAX
from gatewaylab.devices.ecanlite.mcan.registers import IR_FULL, IR_LOST, IR_NEW, IR_RF0F, IR_TC
from gatewaylab.devices.ecanlite.stream import TxResultCode

__all__ = [
    "ChannelCounters",
    "DataPath",
    "DataPathPolicy",
    "Degraded",
    "EventFlag",
    "PolicyError",
    "ReceivedFrame",
    "TxEntry",
    "is_critical",
]


class EventFlag(enum.IntFlag):
    """0x900x:12 latched channel event flags (gatewaylab's bit layout, docs/devices/ecanlite-mcan.md)."""

    WARNING = 0x01
    BUS_OFF = 0x02
    RX_PRESSURE = 0x04
    TX_PRESSURE = 0x08
    STATE_CHANGE = 0x10


class Degraded(enum.IntFlag):
    """0x9020:15 degraded state bits (0 = normal)."""

    RX_OVERFLOW = 0x01
    BUS_OFF = 0x02
    TX_CONGESTION = 0x04


class PolicyError(ConfigError, ValueError):
    """0x802x values that make no policy (apply status 1: the old policy stays)."""


@dataclass(frozen=True, slots=True)
class ReceivedFrame:
    """A frame the channel accepted: the frame, the bus receive instant (clock seconds) and the
    Message RAM store it sits in (0 RX FIFO0, 1 RX FIFO1, 2 RX buffers; 13.4 filter action)."""

    frame: CanFrame
    t: float
    fifo: int = 0


@dataclass(frozen=True, slots=True, eq=False)
class TxEntry:
    """A frame handed to the channel for transmission and the caller's reference its result
    comes back with (compared by identity: the same frame may be queued twice)."""

    frame: CanFrame
    ref: object


# -- 0x8021..0x8024 data-path policy ------------------------------------------------------------------
#: 0x802x:07 legacy enum -> depth, and back (13.2.2 RX cache depth table).
_DEPTH_OF = {0: 32, 1: 8, 2: 16, 3: 24, 8: 8, 16: 16, 24: 24, 32: 32}
_ENUM_OF_DEPTH = {32: 0, 8: 1, 16: 2, 24: 3}


@dataclass(frozen=True, slots=True)
class DataPathPolicy:
    """An applied 0x802x policy (13.2.2)."""

    enable: bool = True
    rx_drain_min: int = 0
    rx_drain_max: int = 2
    rx_budget_policy: int = 1
    #: 0x802x:07 as written: legacy enum 0..3 or explicit 8/16/24/32 (see :attr:`depth`).
    rx_cache_depth: int = 2
    rx_overflow: int = 1
    critical: int = 1
    id_priority: int = 0
    tx_budget_min: int = 0
    tx_budget_max: int = 4
    tx_overflow: int = 1
    busoff_recovery: int = 1
    backoff_base: int = 2
    degraded_threshold: int = 64

    @classmethod
    def from_values(cls, v: Mapping[int, int]) -> DataPathPolicy:
        """Check 0x802x values; :class:`PolicyError` says what is wrong (apply status 1)."""
        def g(sub: int) -> int:
            return int(v.get(sub, POLICY_DEFAULTS[sub]))
        for sub, hi in ((1, 1), (4, 8), (5, 8), (6, 3), (8, 3), (9, 2), (11, 8), (12, 8), (13, 3), (14, 3)):
            if g(sub) > hi:
                raise PolicyError(f"0x802x:{sub} = {g(sub)} outside 0..{hi}")
        if g(4) > g(5) or g(11) > g(12):
            raise PolicyError("budget min above budget max")
        if g(7) not in _DEPTH_OF:
            raise PolicyError(f"RX cache depth {g(7)} is neither 0..3 nor 8/16/24/32")
        return cls(g(1) == 1, g(4), g(5), g(6), g(7), g(8), g(9), g(10), g(11), g(12), g(13),
                   g(14), g(15), g(16))

    @property
    def depth(self) -> int:
        """RX cache depth in frames."""
        return _DEPTH_OF[self.rx_cache_depth]

    @property
    def control_word(self) -> int:
        """0x802x:20 packed echo (13.2.2 bit table)."""
        return ((int(self.enable)) | (self.rx_drain_min & 0xF) << 4 | (self.rx_drain_max & 0xF) << 8
                | (self.rx_budget_policy & 3) << 12 | _ENUM_OF_DEPTH[self.depth] << 14
                | (self.rx_overflow & 3) << 16 | (self.critical & 3) << 18 | (self.tx_budget_min & 0xF) << 20
                | (self.tx_budget_max & 0xF) << 24 | (self.tx_overflow & 3) << 28
                | (self.busoff_recovery & 3) << 30)


# -- CANopen critical frames (0x802x:09) --------------------------------------------------------------
def is_critical(frame: CanFrame, policy: int) -> bool:
    """Critical-frame classes of 13.2.2: 1 'CANopen safety' = NMT (0x000), SYNC (0x080), EMCY
    (0x081..0x0FF) and NMT error control / heartbeat (0x701..0x77F); 2 'CANopen all' adds TIME
    (0x100), SDO (0x581..0x5FF, 0x601..0x67F) and LSS (0x7E4/0x7E5). Standard identifiers only."""
    if policy == 0 or frame.extended:
        return False
    cid = frame.can_id
    if cid == 0x000 or 0x080 <= cid <= 0x0FF or 0x701 <= cid <= 0x77F:
        return True
    return policy >= 2 and (cid == 0x100 or 0x581 <= cid <= 0x5FF or 0x601 <= cid <= 0x67F
                            or cid in (0x7E4, 0x7E5))


@dataclass(slots=True)
class ChannelCounters:
    """0x9000 / 0x9020 counters of one channel."""

    rx_high_watermark: int = 0
    rx_drain_last: int = 0
    rx_drain_max: int = 0
    rx_dropped_total: int = 0
    rx_dropped_old: int = 0
    rx_dropped_new: int = 0
    rx_dropped_critical: int = 0
    consumed_last: int = 0
    consumed_max: int = 0
    tx_fifo_full: int = 0
    tx_stale_dropped: int = 0
    bus_off: int = 0
    recovery_attempts: int = 0
    last_error: int = 0
    rx_policy_drops: int = 0
    tx_policy_refusals: int = 0
    error_log: int = 0
    detail_sequence: int = 0


class DataPath:
    """RX cache, TX FIFO/queue and TX ring of one channel under its 0x802x policy (13.2.2), with
    the counters, pressure flags, latched events and degraded state they report (13.5)."""

    def __init__(self, clock: Clock, loopback: Callable[[CanFrame, float], None]) -> None:
        """``loopback`` receives the frames sent in internal loopback mode (the channel's RX)."""
        self.clock = clock
        self.loopback = loopback
        self.policy = DataPathPolicy()
        self.counters = ChannelCounters()
        self.rx: deque[ReceivedFrame] = deque()
        #: Frames of each RX store (FIFO0, FIFO1, RX buffers) in the cache; lost flags (RXFnS.RFnL).
        self.fill = [0] * RX_STORES
        self.lost = [False] * RX_STORES
        #: Frames in the MCAN TX FIFO/queue (handed to the bus controller, not finished).
        self.tx: deque[TxEntry] = deque()
        #: The firmware TX ring: frames over this cycle's TX budget (0x802x:12), not yet in the MCAN.
        self.ring: deque[TxEntry] = deque()
        self.tx_served = 0
        self.results: list[tuple[object, int]] = []
        self.events = EventFlag(0)
        self.detail_pending = False
        self.degraded = Degraded(0)
        self.backoff_cycles = 0
        self.backoff_level = 0
        self.rx_recent_drop = False
        self.tx_recent_full = False
        #: The M_CAN interrupt register's latched bits (IR, write 1 to clear).
        self.ir = 0

    @property
    def depth(self) -> int:
        """RX cache depth in frames under the applied policy (the maximum when disabled)."""
        return self.policy.depth if self.policy.enable else RX_CACHE_MAX

    def apply_policy(self, policy: DataPathPolicy) -> None:
        """A new policy (0x802x:02 = 1): ends a degraded state and TX backoff; the cache keeps what
        fits its new depth (the oldest frames go)."""
        self.policy = policy
        self.degraded = Degraded(0)
        c = self.counters
        c.rx_policy_drops = c.tx_policy_refusals = 0
        self.backoff_cycles = self.backoff_level = 0
        while len(self.rx) > self.depth:
            self.fill[self.rx.popleft().fifo] -= 1
            c.rx_dropped_old += 1
            c.rx_dropped_total += 1

    def clear_rx(self) -> None:
        """A firmware restart: the RX cache is emptied."""
        self.rx.clear()
        self.fill = [0] * RX_STORES

    def forget_tx(self) -> None:
        """The firmware stops: frames in the TX FIFO and ring are forgotten, without results."""
        self.tx.clear()
        self.ring.clear()

    def clear_diagnostics(self) -> None:
        """0xB000 bit 5: counters, latched flags, the degraded state and IR back to zero."""
        self.counters = ChannelCounters()
        self.events = EventFlag(0)
        self.detail_pending = False
        self.degraded = Degraded(0)
        self.ir = 0
        self.lost = [False] * RX_STORES

    # -- bookkeeping (one copy for both directions) ----------------------------------------------
    def latch(self, flag: EventFlag) -> None:
        """Latch an event flag (0x900x:12); a newly set flag counts the detail sequence."""
        if not self.events & flag:
            self.events |= flag
            self.counters.detail_sequence += 1
        self.detail_pending = True

    def _pressure(self, count: int, overflow_policy: int, flag: EventFlag, state: Degraded) -> None:
        """A drop or refusal happened: latch the pressure flag, and under overflow policy 3 enter the
        degraded ``state`` once ``count`` reaches the degraded threshold (0x802x:16)."""
        self.latch(flag)
        p = self.policy
        if p.enable and overflow_policy == 3 and count >= p.degraded_threshold:
            self.degraded |= state

    def _rx_dropped(self, store: int) -> None:
        """One received frame lost (its own counter already counted): totals, RFnL, pressure."""
        c = self.counters
        c.rx_dropped_total += 1
        c.rx_policy_drops += 1
        self.lost[store] = self.rx_recent_drop = True
        self.ir |= IR_LOST[store]
        self._pressure(c.rx_policy_drops, self.policy.rx_overflow, EventFlag.RX_PRESSURE, Degraded.RX_OVERFLOW)

    def _tx_refused(self) -> None:
        """One frame refused with TX_FIFO_FULL: counters, pressure."""
        c = self.counters
        c.tx_fifo_full += 1
        c.tx_policy_refusals += 1
        self.tx_recent_full = True
        self._pressure(c.tx_policy_refusals, self.policy.tx_overflow, EventFlag.TX_PRESSURE,
                       Degraded.TX_CONGESTION)

    def _drop_oldest_rx(self) -> None:
        self.fill[self.rx.popleft().fifo] -= 1
        self.counters.rx_dropped_old += 1
        self._rx_dropped(0)

    # -- receive path ------------------------------------------------------------------------------
    def receive(self, frame: CanFrame, t: float, store: int, rt: ChannelRuntime) -> None:
        """An accepted frame enters Message RAM ``store`` (13.4 :61/:63 op mode when it is full),
        then the firmware RX cache (0x802x:07/:08/:09 when that is full)."""
        size = rt.rx_store_bytes[store]
        if len(frame.data) > size:
            # M_CAN stores only the element's data field; the DLC stays: the rest reads as zero
            frame = replace(frame, data=frame.data[:size].ljust(len(frame.data), b"\0"))
        self.ir |= IR_NEW[store]
        fill = self.fill
        if fill[store] >= rt.rx_sizes[store]:
            # the Message RAM FIFO / buffers are full: blocking loses the new frame (RFnL),
            # overwrite gives up the oldest frame of that FIFO
            self.ir |= IR_FULL[store]
            if rt.rx_overwrite[store] and fill[store]:
                rx = self.rx
                for i, old in enumerate(rx):
                    if old.fifo == store:
                        del rx[i]
                        fill[store] -= 1
                        break
                self.counters.rx_dropped_old += 1
            else:
                self.counters.rx_dropped_new += 1
                self._rx_dropped(store)
                return
            self._rx_dropped(store)
        self._store(ReceivedFrame(frame, t, store))

    def _store(self, rf: ReceivedFrame) -> None:
        rx = self.rx
        fill = self.fill
        if len(rx) >= self.depth:
            self.ir |= IR_RF0F
            p = self.policy
            policy = p.rx_overflow if p.enable else 1
            if policy == 0:
                self._drop_oldest_rx()
            elif policy == 2 and is_critical(rf.frame, p.critical):
                for i, old in enumerate(rx):
                    if not is_critical(old.frame, p.critical):
                        del rx[i]
                        fill[old.fifo] -= 1
                        self.counters.rx_dropped_critical += 1
                        self._rx_dropped(0)
                        break
                else:
                    self._drop_oldest_rx()
            else:
                self.counters.rx_dropped_new += 1
                self._rx_dropped(rf.fifo)
                return
        rx.append(rf)
        fill[rf.fifo] += 1
        if len(rx) > self.counters.rx_high_watermark:
            self.counters.rx_high_watermark = len(rx)

    def drain_budget(self) -> int:
        """Frames one TxPDO build may take from the RX cache (0x802x:04..06): limited = the max
        budget, balanced = at least 2, performance = everything, adaptive = the max budget, or
        everything once the cache is half full. Disabled policy = everything."""
        p = self.policy
        if not p.enable or p.rx_budget_policy == 2:
            return RX_CACHE_MAX
        if p.rx_budget_policy == 3 and 2 * len(self.rx) >= self.depth:
            return RX_CACHE_MAX
        if p.rx_budget_policy == 0:
            return max(2, p.rx_drain_max)
        return p.rx_drain_max

    def peek(self, limit: int) -> Sequence[ReceivedFrame]:
        """The oldest received frames, at most ``limit`` and the drain budget (not removed)."""
        n = min(limit, self.drain_budget(), len(self.rx))
        if n <= 0:
            return ()
        rx = self.rx
        return tuple(rx[i] for i in range(n))

    def consume(self, n: int) -> None:
        """Remove the ``n`` oldest frames (they went into a TxPDO)."""
        n = max(0, min(n, len(self.rx)))
        rx, fill = self.rx, self.fill
        for _ in range(n):
            fill[rx.popleft().fifo] -= 1
        c = self.counters
        c.rx_drain_last = c.consumed_last = n
        c.rx_drain_max = max(c.rx_drain_max, n)
        c.consumed_max = max(c.consumed_max, n)

    def pending_tx(self) -> int:
        """Frames handed to the channel and not finished (in the TX ring or the MCAN)."""
        return len(self.tx) + len(self.ring)

    # -- transmit path ---------------------------------------------------------------------------
    def offer(self, entry: TxEntry, c: Controller, rt: ChannelRuntime) -> int:
        """A frame for a running channel: TX backoff, the TX overflow policy (0x802x:13) when the
        MCAN elements and the ring are full, then the MCAN or, over this cycle's TX budget, the
        ring. 0 = queued, else the TxResultCode to report at once."""
        p = self.policy
        if self.backoff_cycles > 0:
            self._tx_refused()
            return TxResultCode.TX_FIFO_FULL
        if len(self.tx) + len(self.ring) >= rt.tx_elements:
            policy = p.tx_overflow if p.enable else 0
            if not (policy == 1 and rt.node_mode is not NodeMode.INTERNAL_LOOPBACK and self._drop_oldest_tx(c)):
                self._tx_refused()
                if policy == 2:
                    self.backoff_level = min(self.backoff_level + 1, 6)
                    self.backoff_cycles = max(1, p.backoff_base) << (self.backoff_level - 1)
                return TxResultCode.TX_FIFO_FULL
        frame = entry.frame
        if len(frame.data) > rt.tx_data_bytes:
            frame = replace(frame, data=frame.data[:rt.tx_data_bytes].ljust(len(frame.data), bytes((TX_PAD,))))
            entry = TxEntry(frame, entry.ref)
        if p.enable and (self.ring or self.tx_served >= p.tx_budget_max):
            # 13.2.2 SI12: at most 'TX budget max' frames per cycle go to the MCAN; the rest wait in
            # the firmware TX ring (same capacity) for the next cycles (serve_ring), in order
            self.ring.append(entry)
            return TxResultCode.OK
        return self.to_mcan(entry, c, rt)

    def to_mcan(self, entry: TxEntry, c: Controller | None, rt: ChannelRuntime | None) -> int:
        """Hand one frame to the MCAN TX FIFO/queue (one unit of this cycle's TX budget)."""
        if c is None or rt is None or rt.node_mode in (NodeMode.LISTEN, NodeMode.RESTRICTED):
            return TxResultCode.INVALID_CHANNEL
        if c.state is ErrorState.BUS_OFF:
            return TxResultCode.BUS_OFF
        self.tx_served += 1
        self.tx.append(entry)
        if rt.node_mode is NodeMode.INTERNAL_LOOPBACK:
            self.clock.call_soon(self._looped, entry)
            return TxResultCode.OK
        try:
            if rt.tx_queue_mode:
                c.send_by_priority(entry.frame)
            else:
                c.send(entry.frame)
        except GatewaylabError:
            self.tx.pop()
            return TxResultCode.INVALID_CHANNEL
        return TxResultCode.OK

    def _drop_oldest_tx(self, c: Controller) -> bool:
        """TX overflow policy 'drop oldest': the oldest frame not yet on the wire is given up."""
        for i, entry in enumerate(self.tx):
            if c.withdraw(entry.frame):
                del self.tx[i]
                self._stale(entry)
                return True
        if self.ring:
            self._stale(self.ring.popleft())
            return True
        return False

    def _stale(self, entry: TxEntry) -> None:
        self.counters.tx_stale_dropped += 1
        self.results.append((entry.ref, TxResultCode.TX_FIFO_FULL))

    def _looped(self, entry: TxEntry) -> None:
        if entry in self.tx:
            self.tx.remove(entry)
            self.results.append((entry.ref, TxResultCode.OK))
            self.ir |= IR_TC
            self.loopback(entry.frame, self.clock.now())

    def finish(self, frame: CanFrame, result: TxResultCode) -> None:
        """The bus ended the transmission of ``frame`` (sent or aborted): its result is due."""
        for i, entry in enumerate(self.tx):
            if entry.frame is frame:
                del self.tx[i]
                self.results.append((entry.ref, result))
                return

    def withdraw_all(self, c: Controller) -> None:
        """Give every unfinished frame back (pin rotation, reset): queued ones are taken back from
        the controller and aborted (ResultCode 2); the one on the wire completes (OK)."""
        on_wire = c.bus.on_wire
        busy = on_wire.frame if on_wire is not None and on_wire.sender is c else None
        for entry in list(self.tx):
            if entry.frame is busy:
                continue
            c.withdraw(entry.frame)
            self.tx.remove(entry)
            self.results.append((entry.ref, TxResultCode.BUS_BUSY))
        while self.ring:
            self.results.append((self.ring.popleft().ref, TxResultCode.BUS_BUSY))
        if busy is not None:
            for entry in list(self.tx):
                self.tx.remove(entry)
                self.results.append((entry.ref, TxResultCode.OK))

    def serve_ring(self, c: Controller | None, rt: ChannelRuntime | None) -> None:
        """Per-cycle tick: a new TX budget (0x802x:12) serves the firmware TX ring; TX backoff
        counts down."""
        self.tx_served = 0
        ring = self.ring
        if ring:
            budget = self.policy.tx_budget_max if self.policy.enable else len(ring)
            while ring and self.tx_served < budget:
                entry = ring.popleft()
                code = self.to_mcan(entry, c, rt)
                if code:
                    self.results.append((entry.ref, code))
        if self.backoff_cycles > 0:
            self.backoff_cycles -= 1
            if self.backoff_cycles == 0 and not self.tx_recent_full:
                self.backoff_level = 0
