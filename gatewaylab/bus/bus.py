"""Virtual CAN / CAN FD bus: arbitration and frame timing (the engine every frame goes through).

Sans-I/O: the bus schedules everything on the injected :class:`~gatewaylab.common.clock.Clock`
and talks to its users through callbacks. The model is documented in ``docs/bus.md``. The rooms
around it: :mod:`~gatewaylab.bus.controller` (a controller, its fault confinement and events),
:mod:`~gatewaylab.bus.transmission` (what arbitration puts on the wire), :mod:`~gatewaylab.bus.audience`
(who hears, acknowledges and receives), :mod:`~gatewaylab.bus.stats` (counters) and
:mod:`~gatewaylab.bus.faults` (fault injection). The bus implements what its controllers and its
fault injector ask of it (``ControllerBus``, ``FaultedBus``: the methods under "the parts' side"
below) and drives its controllers through their public methods. The package
:mod:`gatewaylab.bus` re-exports the names users need.
"""

from __future__ import annotations

from gatewaylab.bus.audience import Audience
from gatewaylab.bus.controller import (
    Controller,
    ErrorKind,
    ErrorState,
    EventCallback,
    FrameCallback,
    TxAbortedEvent,
    TxDoneEvent,
)
from gatewaylab.bus.faults import BusFaults, FaultPlan
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.stats import BusStats, ControllerStats
from gatewaylab.bus.timing import arbitration_key, classic_durations, error_duration, frame_duration
from gatewaylab.bus.transmission import Outcome, Step, Transmission
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import ConfigError

__all__ = ["ZERO_TIME_BURST", "VirtualBus"]

#: Enum members as module constants for the per-frame paths (attribute access on an Enum class
#: costs about 80 ns in Python 3.11, a global about 10 ns).
_BUS_OFF = ErrorState.BUS_OFF
_ACTIVE = ErrorState.ERROR_ACTIVE

#: Frames that take no time (a bus without frame timing) end at once, at most this many in a
#: row; then the bus goes on in a new clock event (see VirtualBus._arbitrate).
ZERO_TIME_BURST = 32

_SENT = Outcome.SENT
_DROPPED = Outcome.DROPPED
_ACK_ERROR = Outcome.ACK_ERROR
_CRC_ERROR = Outcome.CRC_ERROR


class VirtualBus:
    """A CAN or CAN FD bus segment; any number per process, any number of controllers each."""

    def __init__(self, clock: Clock, name: str = "can0", bitrate: int = 1_000_000,
                 data_bitrate: int | None = None, timing: bool = True) -> None:
        if bitrate <= 0 or (data_bitrate is not None and data_bitrate <= 0):
            raise ConfigError(f"bus {name}: bit rates must be positive")
        self.clock = clock
        self.name = name
        self._bitrate = bitrate
        self._data_bitrate = data_bitrate
        #: durations of classic base frames with 0..8 data bytes at the bit rate
        self._classic_times = classic_durations(bitrate)
        #: False: frames take no time (ordering and arbitration still apply). For load tests.
        self.timing = timing
        self.controllers: list[Controller] = []
        #: Cached audience (see _audience); None = build again. Dropped by audience_changed whenever
        #: something changes who hears, acknowledges or sends a frame, or through which callback.
        self._receivers: Audience | None = None
        self.stats = BusStats(since=clock.now())
        self._monitors: list[FrameCallback] = []
        #: The transmission on the wire, until its end of frame has been handled.
        self._on_wire: Step | None = None
        #: The pending arbitration a queued frame asked for (see request_arbitration).
        self._arb_timer: TimerHandle | None = None
        self._idle_at = clock.now()
        #: Faults planned for the next transmissions (docs/bus.md): the fault injector puts a plan
        #: here, the bus drops it when spent; None costs the hot path one test.
        self.fault_plan: FaultPlan | None = None
        #: One end of frame and one arbitration are pending at most: each has one handle that
        #: the bus queues again (clock.reschedule) instead of a new handle per frame.
        self._eof_handle = TimerHandle(0.0, 0, self._end_of_frame, ())
        self._arb_handle = TimerHandle(0.0, 0, self._arbitrate, ())
        #: The fault injector (gatewaylab.bus.faults): the fault methods below call it.
        self.faults = BusFaults(self)

    def __repr__(self) -> str:
        fd = f"/{self.data_bitrate}" if self.data_bitrate else ""
        return f"<VirtualBus {self.name} {self.bitrate}{fd} bit/s, {len(self.controllers)} controllers>"

    @property
    def is_fd(self) -> bool:
        """True for a CAN FD bus (it has a data bit rate)."""
        return self._data_bitrate is not None

    @property
    def bitrate(self) -> int:
        """The nominal (arbitration) bit rate in bit/s."""
        return self._bitrate

    @bitrate.setter
    def bitrate(self, value: int) -> None:
        """Re-time the whole segment (e.g. after an LSS bit-timing switch); controllers re-check."""
        self._bitrate = value
        self._classic_times = classic_durations(value)
        for c in self.controllers:
            c.check_timing()

    @property
    def data_bitrate(self) -> int | None:
        """The CAN FD data-phase bit rate in bit/s; None on a classic bus."""
        return self._data_bitrate

    @data_bitrate.setter
    def data_bitrate(self, value: int | None) -> None:
        self._data_bitrate = value
        for c in self.controllers:
            c.check_timing()

    # -- attachment -------------------------------------------------------------------------
    def attach(self, name: str = "", *, bitrate: int | None = None, data_bitrate: int | None = None,
               listen_only: bool = False, auto_retransmit: bool = True, receive_own: bool = False,
               fd: bool = True, auto_recover: bool = True, on_frame: FrameCallback | None = None,
               on_event: EventCallback | None = None) -> Controller:
        """Attach a controller. Its bit rates default to the bus's own."""
        ctrl = Controller(self, name or f"ctrl{len(self.controllers)}", bitrate or self.bitrate,
                          data_bitrate or self.data_bitrate, listen_only, auto_retransmit,
                          receive_own, fd, auto_recover, on_frame, on_event)
        self.controllers.append(ctrl)
        ctrl.check_timing()
        return ctrl

    def detach(self, ctrl: Controller) -> None:
        """Remove a controller: its queue is dropped, it takes part in no frame any more."""
        if ctrl in self.controllers:
            self.controllers.remove(ctrl)
            ctrl.connected = False
            self.audience_changed()
            ctrl.tx_queue.clear()

    def add_monitor(self, callback: FrameCallback) -> None:
        """Call ``callback(frame, t)`` for every frame that completes on the bus (for traces)."""
        self._monitors.append(callback)

    def remove_monitor(self, callback: FrameCallback) -> None:
        """Stop calling a callback given to :meth:`add_monitor` (unknown ones are ignored)."""
        if callback in self._monitors:
            self._monitors.remove(callback)

    @property
    def busy(self) -> bool:
        """True while a frame is on the wire or any connected controller has one queued."""
        return self.is_busy()

    def is_busy(self) -> bool:
        """:attr:`busy` as a method (a cheap condition for ``clock.run_while``)."""
        if self._on_wire is not None or self._arb_timer is not None:
            return True
        for c in self.controllers:
            if (c.tx_queue and c.connected and c.state is not _BUS_OFF and c.timing_matches
                    and not c.synthetic):
                return True
        return False

    # -- fault injection (gatewaylab.bus.faults.BusFaults; here for the callers of the bus) ----
    def disconnect(self, ctrl: Controller) -> None:
        """Unplug a controller (:meth:`BusFaults.disconnect`)."""
        self.faults.disconnect(ctrl)

    def reconnect(self, ctrl: Controller) -> None:
        """Plug a controller back in (:meth:`BusFaults.reconnect`)."""
        self.faults.reconnect(ctrl)

    def force_bus_off(self, ctrl: Controller) -> None:
        """Put a controller bus-off (:meth:`BusFaults.force_bus_off`)."""
        self.faults.force_bus_off(ctrl)

    def force_error_passive(self, ctrl: Controller) -> None:
        """Put a controller error-passive (:meth:`BusFaults.force_error_passive`)."""
        self.faults.force_error_passive(ctrl)

    def drop_next(self, n: int = 1, can_id: int | None = None) -> None:
        """The next ``n`` frames (of ``can_id``) vanish (:meth:`BusFaults.drop_next`)."""
        self.faults.drop_next(n, can_id)

    def corrupt_next(self, n: int = 1, can_id: int | None = None) -> None:
        """The next ``n`` frames (of ``can_id``) end in a CRC error (:meth:`BusFaults.corrupt_next`)."""
        self.faults.corrupt_next(n, can_id)

    def error_frames(self, duration: float, every: int = 1) -> None:
        """Noise for ``duration`` seconds (:meth:`BusFaults.error_frames`)."""
        self.faults.error_frames(duration, every)

    def stuck_dominant(self, duration: float) -> None:
        """Hold the bus dominant for ``duration`` seconds (:meth:`BusFaults.stuck_dominant`)."""
        self.faults.stuck_dominant(duration)

    @property
    def stuck(self) -> bool:
        """True while the bus is held dominant (:meth:`stuck_dominant`)."""
        return self.faults.stuck

    def set_load(self, percent: float, can_id: int = 0x7FF, length: int = 8) -> None:
        """Synthetic bus load from a phantom node, 0 disables (:meth:`BusFaults.set_load`)."""
        self.faults.set_load(percent, can_id, length)

    # -- statistics --------------------------------------------------------------------------
    def load_percent(self) -> float:
        """Share of time the bus was busy since the statistics were reset."""
        elapsed = self.clock.now() - self.stats.since
        return 100.0 * self.stats.busy_time / elapsed if elapsed > 0 else 0.0

    def reset_stats(self) -> None:
        """Start the bus's and every controller's counters from zero, now."""
        self.stats = BusStats(since=self.clock.now())
        self.settle_rx()
        for c in self.controllers:
            c.counters = ControllerStats()

    # -- who takes part ----------------------------------------------------------------------
    def _audience(self) -> Audience:
        """Who takes part in the next frames (see :class:`Audience`), cached until :meth:`audience_changed`."""
        audience = self._receivers
        if audience is None:
            audience = self._receivers = Audience(self.controllers)
        return audience

    # -- the parts' side (ControllerBus: the controllers; FaultedBus: the fault injector) ------
    def audience_changed(self) -> None:
        """Who hears, acknowledges or sends frames, or through which callback, may change (a
        controller's settings or state, attachment): settle the receive counters of the present
        audience and forget it; the next frame builds it again."""
        audience = self._receivers
        if audience is not None:
            audience.rx.settle(audience.hear)
            self._receivers = None

    def settle_rx(self) -> None:
        """Bring every controller's receive counters up to date (before they are read)."""
        audience = self._receivers
        if audience is not None:
            audience.rx.settle(audience.hear)

    def request_arbitration(self) -> None:
        """A frame is waiting: arbitrate as soon as the bus is idle. While a frame is on the wire
        nothing is scheduled: its end of frame arbitrates the next one."""
        if self._on_wire is None and self._arb_timer is None:
            clock = self.clock
            self._arb_timer = handle = self._arb_handle
            clock.reschedule(handle, max(clock.now(), self._idle_at))

    def hold(self, now: float) -> None:
        """Occupy the bus from ``now`` (a bus held dominant): the frame on the wire and a pending
        arbitration are cancelled, nothing arbitrates until :meth:`release`; meanwhile
        :attr:`on_wire` names a placeholder sender that no controller is."""
        # a cancelled handle stays in the clock's queue: the bus takes fresh ones, so that a later
        # reschedule of the same handle cannot revive the stale entry
        if self._on_wire is not None:
            self._eof_handle.cancel()
            self._eof_handle = TimerHandle(0.0, 0, self._end_of_frame, ())
        if self._arb_timer is not None:
            self._arb_timer.cancel()
            self._arb_timer = None
            self._arb_handle = TimerHandle(0.0, 0, self._arbitrate, ())
        holder = Controller(self, "<stuck dominant>", self._bitrate, None, False, False, False, False,
                            False, None, None)
        self._on_wire = (holder, CanFrame(0), _ACK_ERROR, now, now)

    def release(self, now: float) -> None:
        """The bus is idle again from ``now`` (the end of :meth:`hold`); the caller asks for the
        arbitration of the frames queued meanwhile."""
        self._idle_at = now
        self._on_wire = None

    # -- the arbitration engine --------------------------------------------------------------
    @property
    def on_wire(self) -> Transmission | None:
        """The transmission on the wire now (None when idle): who sends which frame, so a device can
        leave the frame it is sending alone when it edits its own transmit queue."""
        step = self._on_wire
        return None if step is None else Transmission(*step)

    def next_transmission(self, start: float) -> Transmission | None:
        """The arbitration step: which queued frame wins at ``start`` (the lowest arbitration
        field), how its transmission ends and when. It reads the bus and changes nothing."""
        step = self._arbitration(start)
        return None if step is None else Transmission(*step)

    def _arbitration(self, start: float) -> Step | None:
        """:meth:`next_transmission` as the engine's tuple (the one implementation)."""
        audience = self._receivers or self._audience()
        sender: Controller | None = None
        best = 0
        for c in audience.senders:
            queue = c.tx_queue
            if queue:
                head = queue[0]
                if head is not c.arb_head:
                    c.arb_head = head
                    c.arb_key = arbitration_key(head)
                key = c.arb_key
                if sender is None or key < best:
                    sender, best = c, key
        if sender is None:
            return None
        frame = sender.tx_queue[0]
        # acknowledged when a controller other than the sender acknowledges (an FD frame: an FD one)
        acks = audience.fd_acks if frame.fd else audience.acks
        if sender.synthetic:
            outcome = _SENT
        elif self.fault_plan is not None and (planned := self.fault_plan.outcome(frame, start)) is not None:
            outcome = planned
        elif acks and (acks[0] is not sender or len(acks) > 1):
            outcome = _SENT
        else:
            outcome = _ACK_ERROR
        if outcome is _SENT or outcome is _DROPPED:
            if not self.timing:
                duration = 0.0
            elif frame.fd or frame.extended:
                duration = frame_duration(frame, self._bitrate, self._data_bitrate)
            else:   # the common classic base frame: looked up, not computed
                duration = self._classic_times[len(frame.data)]
        else:
            # an error frame takes its time even on a bus without frame timing: a lone sender
            # retransmits for ever, and that must not stop the clock (docs/decisions.md)
            duration = error_duration(frame, sender.state is ErrorState.ERROR_PASSIVE,
                                      self._bitrate, self._data_bitrate)
        return sender, frame, outcome, start, start + duration

    def _arbitrate(self, start: float | None = None) -> None:
        """Put the next frame on the wire at ``start`` (default now) and schedule its end: in real
        time a late wake-up must not stretch the frame schedule, so back-to-back frames start at
        the previous frame's end. A frame that takes no time (a bus without frame timing) ends at
        once; after ZERO_TIME_BURST of them in a row the bus goes on in a new clock event, so the
        clock's owner keeps control (a real-time rig serves its clients in between)."""
        self._arb_timer = None
        if self._on_wire is not None:
            return
        now = self.clock.now() if start is None else start
        burst = 0
        while True:
            step = self._arbitration(now)
            if step is None:
                return
            end = step[4]
            if self.fault_plan is not None and self.fault_plan.commit(step):
                self.fault_plan = None
            self._on_wire = step
            if end != now:
                self.clock.reschedule(self._eof_handle, end)
                return
            burst += 1
            try:
                self._end_of_frame(False)
            except BaseException:
                self.request_arbitration()   # the frames still queued go on in a clock event of their own
                raise
            if burst == ZERO_TIME_BURST:
                self.request_arbitration()
                return

    def _end_of_frame(self, arbitrate: bool = True) -> None:
        """The transmission on the wire ends: account for it (queue, counters, delivery, events,
        fault confinement), then, in its own clock event, arbitrate the next frame at this
        instant. The bus counts as busy until then, so frames that receivers send meanwhile wait
        for that arbitration."""
        step = self._on_wire
        assert step is not None
        sender, frame, outcome, start, end = step
        try:
            self._idle_at = end
            stats = self.stats
            stats.busy_time += end - (start if start > stats.since else stats.since)
            queue = sender.tx_queue
            if outcome is _SENT or outcome is _DROPPED:
                if not queue or queue[0] is not frame:
                    return  # the sender was detached mid-frame: the frame completes for nobody
                queue.popleft()
                n = len(frame.data)
                st = sender.counters
                st.tx_frames += 1
                st.tx_bytes += n
                if sender.tec:   # every success takes one off TEC (CAN 2.0 §8 rule 7)
                    sender.tec -= 1
                    if sender.state is not _ACTIVE:
                        sender.update_state()
                if outcome is _SENT:
                    stats.frames += 1
                    stats.bytes += n
                    self._deliver(sender, frame, end)
                else:
                    stats.dropped_frames += 1
                    self._foreign_errors(end)
                if sender.on_event is not None:
                    sender.on_event(TxDoneEvent(frame, end))
                return
            stats.error_frames += 1
            kind = ErrorKind.ACK if outcome is _ACK_ERROR else ErrorKind.CRC
            sender.counters.tx_retransmissions += 1
            sender.count_error(kind, True, frame, end)
            if kind is ErrorKind.CRC:
                for c in self._audience().hear:
                    if c is not sender:
                        c.count_error(kind, False, frame, end)
            if (not sender.auto_retransmit and sender.state is not _BUS_OFF
                    and queue and queue[0] is frame):
                queue.popleft()
                sender.emit(TxAbortedEvent(frame, end, "single-shot"))
            self._foreign_errors(end)
        finally:
            self._on_wire = None
            if arbitrate:
                self._arbitrate(end)

    def _deliver(self, sender: Controller, frame: CanFrame, now: float) -> None:
        """Hand a completed frame to everyone who hears it: its sender with ``receive_own``, the
        receivers of its route (all at the same instant, as decided when the frame ended; a
        receiver with REC > 0 counts it down first), foreign-rate controllers (a form error) and
        the monitors."""
        audience = self._receivers or self._audience()
        audience.rx.count(sender, frame)
        if sender.receive_own and (own := sender.on_frame) is not None:
            own(frame, now)
        # the kind of frame (see _Routes): its receivers are looked up, built on first use
        fd = frame.fd
        kind = (-2 if fd else -1) if frame.extended else (frame.can_id + 0x800 if fd else frame.can_id)
        for c, cb in audience.routes[kind]:
            if c is not sender:
                if c.rec:
                    c.count_received()
                if cb is not None:
                    cb(frame, now)
        if audience.foreign:     # (an empty loop still builds an iterator: once per frame)
            for c in audience.foreign:
                c.count_error(ErrorKind.FORM, False, None, now)  # a foreign bit rate sees only garbage
        if self._monitors:
            for monitor in self._monitors:
                monitor(frame, now)

    def _foreign_errors(self, now: float) -> None:
        """Controllers at another bit rate see every frame as a form error (and nothing else)."""
        for c in self._audience().foreign:
            c.count_error(ErrorKind.FORM, False, None, now)

