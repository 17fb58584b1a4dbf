"""Virtual CAN / CAN FD bus: arbitration, frame timing, ISO 11898-1 fault confinement, faults.

Sans-I/O: the bus schedules everything on the injected :class:`~gatewaylab.common.clock.Clock`
and talks to its users through callbacks. The model is documented in ``docs/bus.md``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from types import MappingProxyType

from ..common.clock import Clock, TimerHandle
from ..common.errors import ConfigError, FrameError, LocalError
from .frame import CanFrame
from .timing import (
    BUS_OFF_RECOVERY_BITS,
    ERROR_FRAME_BITS,
    SUSPEND_TRANSMISSION_BITS,
    arbitration_key,
    frame_bits_until_ack,
    frame_duration,
)


class ErrorState(Enum):
    """Fault-confinement state of a controller (CAN 2.0 §8 'Fault Confinement', carried into ISO 11898-1)."""

    ERROR_ACTIVE = "error-active"
    ERROR_PASSIVE = "error-passive"
    BUS_OFF = "bus-off"


_BUS_OFF = ErrorState.BUS_OFF


class ErrorKind(Enum):
    """Why an error frame was sent."""

    ACK = "ack"          # nobody acknowledged the frame
    CRC = "crc"          # a receiver saw a corrupted frame (fault injection)
    BIT = "bit"          # the controller's bit timing does not match the bus
    FORM = "form"        # a frame sent at a foreign bit rate, seen as garbage


@dataclass(frozen=True, slots=True)
class ErrorFrameEvent:
    """An error frame this controller took part in (as transmitter or receiver)."""

    kind: ErrorKind
    timestamp: float
    transmitter: bool
    frame: CanFrame | None


@dataclass(frozen=True, slots=True)
class StateChangeEvent:
    old: ErrorState
    new: ErrorState
    tec: int
    rec: int
    timestamp: float


@dataclass(frozen=True, slots=True)
class TxDoneEvent:
    """The frame was transmitted and acknowledged (or dropped by fault injection)."""

    frame: CanFrame
    timestamp: float


@dataclass(frozen=True, slots=True)
class TxAbortedEvent:
    """A frame that was given up: single-shot mode after an error, or flushed at bus-off."""

    frame: CanFrame
    timestamp: float
    reason: str


BusEvent = ErrorFrameEvent | StateChangeEvent | TxDoneEvent | TxAbortedEvent
FrameCallback = Callable[[CanFrame, float], None]
EventCallback = Callable[[BusEvent], None]


@dataclass(slots=True)
class ControllerStats:
    tx_frames: int = 0
    rx_frames: int = 0
    tx_bytes: int = 0
    rx_bytes: int = 0
    error_frames: int = 0
    tx_retransmissions: int = 0


@dataclass(slots=True)
class BusStats:
    frames: int = 0
    bytes: int = 0
    error_frames: int = 0
    dropped_frames: int = 0
    busy_time: float = 0.0
    since: float = 0.0


class Controller:
    """One CAN controller attached to a :class:`VirtualBus`."""

    def __init__(self, bus: VirtualBus, name: str, bitrate: int, data_bitrate: int | None,
                 listen_only: bool, auto_retransmit: bool, receive_own: bool, fd: bool,
                 auto_recover: bool, on_frame: FrameCallback | None,
                 on_event: EventCallback | None) -> None:
        self.bus = bus
        self.name = name
        self._bitrate = bitrate
        self._data_bitrate = data_bitrate
        #: Cached: does this controller's bit timing match the bus? (hot path of every frame)
        self.timing_matches = True
        self._listen_only = listen_only
        self.auto_retransmit = auto_retransmit
        self.receive_own = receive_own
        self._fd = fd
        self.auto_recover = auto_recover
        self._on_frame = on_frame
        self._rx_table: dict[int, FrameCallback] | None = None
        self.on_event = on_event
        self.tx_queue: deque[CanFrame] = deque()
        self.tec = 0
        self.rec = 0
        self.state = ErrorState.ERROR_ACTIVE
        self._connected = True
        self._stats = ControllerStats()
        #: frames (bytes) of this controller that the bus delivered in its present audience
        #: epoch: a receiver does not count its own frames (see VirtualBus._settle_rx)
        self._own_frames = 0
        self._own_bytes = 0
        self.synthetic = False
        self._ready_at = 0.0
        self._recovery: TimerHandle | None = None
        self._mismatch_timer: TimerHandle | None = None

    def __repr__(self) -> str:
        return f"<Controller {self.bus.name}/{self.name} {self.state.value} TEC={self.tec} REC={self.rec}>"

    @property
    def stats(self) -> ControllerStats:
        """Frame and error counters (the bus counts received frames per audience and settles
        them here when they are read; under the clock's lock, as deliveries run)."""
        bus = self.bus
        with bus.clock.lock:
            bus._settle_rx()
        return self._stats

    @stats.setter
    def stats(self, value: ControllerStats) -> None:
        bus = self.bus
        with bus.clock.lock:
            bus._settle_rx()
            self._stats = value

    @property
    def on_frame(self) -> FrameCallback | None:
        """``callback(frame, t)`` for every received frame (unless :attr:`rx_table` is set)."""
        return self._on_frame

    @on_frame.setter
    def on_frame(self, value: FrameCallback | None) -> None:
        self._on_frame = value
        self.bus._routes = {}

    @property
    def rx_table(self) -> Mapping[int, FrameCallback] | None:
        """Optional acceptance filter: ``{can_id: callback}`` for standard-format frames. When set,
        the bus calls the callback for that identifier instead of ``on_frame`` and hands this
        controller no extended frames (the controller still receives and counts every frame).
        Assign a new table to change it: the bus keeps a copy (read back as a read-only view)."""
        table = self._rx_table
        return None if table is None else MappingProxyType(table)

    @rx_table.setter
    def rx_table(self, value: Mapping[int, FrameCallback] | None) -> None:
        self._rx_table = None if value is None else dict(value)
        self.bus._routes = {}

    @property
    def fd(self) -> bool:
        """CAN FD capable: receives (and may send) FD frames."""
        return self._fd

    @fd.setter
    def fd(self, value: bool) -> None:
        self.bus._invalidate()
        self._fd = value
        self._check_timing()

    @property
    def connected(self) -> bool:
        return self._connected

    @connected.setter
    def connected(self, value: bool) -> None:
        self.bus._invalidate()
        self._connected = value

    @property
    def listen_only(self) -> bool:
        """Receives without acknowledging or sending (a monitor)."""
        return self._listen_only

    @listen_only.setter
    def listen_only(self, value: bool) -> None:
        self.bus._invalidate()
        self._listen_only = value

    @property
    def bitrate(self) -> int:
        return self._bitrate

    @bitrate.setter
    def bitrate(self, value: int) -> None:
        """Change the nominal bit rate (LSS activate bit timing); the bus re-checks the match."""
        self._bitrate = value
        self._check_timing()

    @property
    def data_bitrate(self) -> int | None:
        return self._data_bitrate

    @data_bitrate.setter
    def data_bitrate(self, value: int | None) -> None:
        self._data_bitrate = value
        self._check_timing()

    def _check_timing(self) -> None:
        """False when this controller's bit timing differs from the bus (it then sees only errors)."""
        bus = self.bus
        bus._invalidate()
        self.timing_matches = self._bitrate == bus.bitrate and not (
            self._fd and bus.data_bitrate is not None and self._data_bitrate is not None
            and self._data_bitrate != bus.data_bitrate)
        if self.timing_matches and self.tx_queue and self.connected:
            bus._kick()

    @property
    def bus_off(self) -> bool:
        return self.state is ErrorState.BUS_OFF

    def send(self, frame: CanFrame) -> None:
        """Queue a frame for transmission (FIFO per controller, like a SocketCAN tx queue)."""
        if self._listen_only:
            raise LocalError(f"{self.name}: a listen-only controller cannot send")
        if frame.fd:
            if not self.fd:
                raise FrameError(f"{self.name}: controller is not CAN FD capable")
            if self.bus.data_bitrate is None:
                raise FrameError(f"bus {self.bus.name} is classic CAN (no data_bitrate): FD frame refused")
        if self.state is _BUS_OFF:
            raise LocalError(f"{self.name}: controller is bus-off")
        self.tx_queue.append(frame)
        if not self._connected:
            return
        if self.timing_matches:
            bus = self.bus
            if bus._in_flight is None and bus._arb_timer is None:
                if bus._ending:
                    bus._kick_deferred = True   # what _kick does while a frame is being delivered
                else:
                    bus._kick()
        elif self._mismatch_timer is None:
            self._mismatch_timer = self.bus.clock.call_soon(self._mismatch_attempt)

    def flush_tx(self) -> None:
        self.tx_queue.clear()

    # -- fault confinement ------------------------------------------------------------------
    def _update_state(self) -> None:
        old = self.state
        if old is ErrorState.BUS_OFF:
            return
        if self.tec > 255:
            new = ErrorState.BUS_OFF
        elif self.tec > 127 or self.rec > 127:
            new = ErrorState.ERROR_PASSIVE
        else:
            new = ErrorState.ERROR_ACTIVE
        if new is not old:
            self._set_state(new)

    def _set_state(self, new: ErrorState) -> None:
        old = self.state
        self.bus._invalidate()
        self.state = new
        clock = self.bus.clock
        if new is ErrorState.BUS_OFF:
            for frame in self.tx_queue:
                self._emit(TxAbortedEvent(frame, clock.now(), "bus-off"))
            self.tx_queue.clear()
            if self.auto_recover:
                self._recovery = clock.call_later(BUS_OFF_RECOVERY_BITS / self.bus.bitrate, self.recover)
        self._emit(StateChangeEvent(old, new, self.tec, self.rec, clock.now()))

    def recover(self) -> None:
        """Leave bus-off (after 128 x 11 recessive bits when ``auto_recover``; or on request)."""
        if self._recovery is not None:
            self._recovery.cancel()
            self._recovery = None
        if self.state is ErrorState.BUS_OFF:
            self.tec = self.rec = 0
            self._set_state(ErrorState.ERROR_ACTIVE)

    def _emit(self, event: BusEvent) -> None:
        if self.on_event is not None:
            self.on_event(event)

    def _error(self, kind: ErrorKind, transmitter: bool, frame: CanFrame | None, t: float) -> None:
        self._stats.error_frames += 1
        if not self.listen_only:
            if transmitter:
                # CAN 2.0 §8 rule 3, exception 1: an error-passive transmitter that
                # detects an ACK error does not increase its TEC, so a lone sender stays passive.
                if not (kind is ErrorKind.ACK and self.state is ErrorState.ERROR_PASSIVE):
                    self.tec += 8
            elif self.rec < 255:
                self.rec += 1
                if self.rec == 1 and self.timing_matches:
                    # a receiver with REC > 0 counts it down with every frame it receives: the
                    # bus delivers receiver by receiver while one is in its audience
                    self.bus._invalidate()
        self._emit(ErrorFrameEvent(kind, t, transmitter, frame))
        self._update_state()

    def _mismatch_attempt(self) -> None:
        """A controller at the wrong bit rate can never send: every attempt is a bit error."""
        self._mismatch_timer = None
        if not self.tx_queue or not self.connected or self.state is ErrorState.BUS_OFF:
            return
        frame = self.tx_queue[0]
        self._error(ErrorKind.BIT, True, frame, self.bus.clock.now())
        if not self.auto_retransmit and self.tx_queue:
            self.tx_queue.popleft()
            self._emit(TxAbortedEvent(frame, self.bus.clock.now(), "single-shot"))
        if self.tx_queue and not self.bus_off:
            self._mismatch_timer = self.bus.clock.call_later(
                ERROR_FRAME_BITS / self.bitrate, self._mismatch_attempt)


#: The frame on the wire: (sender, frame, outcome "ok" | "ack" | "crc" | "drop", start, end);
#: a plain tuple, built once per frame.
_InFlight = tuple[Controller, CanFrame, str, float, float]


class _Audience:
    """Who takes part in frames while nothing changes on the bus (cached by the bus)."""

    __slots__ = ("acks", "eager", "foreign", "hear", "many_acks", "plain", "senders", "sole_ack")

    def __init__(self, controllers: list[Controller]) -> None:
        #: connected, not bus-off, matching bit timing: the controllers that may win arbitration
        self.senders = [c for c in controllers
                        if c._connected and c.state is not _BUS_OFF and c.timing_matches]
        live = [c for c in controllers if c._connected and c.state is not _BUS_OFF and not c.synthetic]
        #: controllers that hear frames (in attachment order)
        self.hear = [c for c in live if c.timing_matches]
        #: controllers at a foreign bit rate: every frame is a form error to them
        self.foreign = [c for c in live if not c.timing_matches]
        #: hearing controllers that acknowledge (not listen-only)
        self.acks = [c for c in self.hear if not c._listen_only]
        #: a classic frame is acknowledged when two or more acknowledge, or one that is not its sender
        self.many_acks = len(self.acks) > 1
        self.sole_ack = self.acks[0] if len(self.acks) == 1 else None
        #: a hearing controller has REC > 0: frames are delivered receiver by receiver
        self.eager = any(c.rec for c in self.hear)
        #: neither of these: a delivery is the route's callbacks and nothing else
        self.plain = not self.eager and not self.foreign


#: receivers of a frame kind with their callbacks and their place in the audience
_Route = tuple[tuple[Controller, FrameCallback, int], ...]


def _route_key(frame: CanFrame) -> int:
    """Frames of one kind reach the same receivers: classic base frames by identifier; FD base
    frames by identifier (in their own range); extended frames by format only."""
    if frame.extended:
        return -2 if frame.fd else -1
    return frame.can_id + 0x800 if frame.fd else frame.can_id


@dataclass(slots=True)
class _Load:
    percent: float
    frame: CanFrame
    timer: TimerHandle | None = None
    controller: Controller | None = field(default=None)


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
        #: False: frames take no time (ordering and arbitration still apply). For load tests.
        self.timing = timing
        self.controllers: list[Controller] = []
        #: Cached audience (see _audience); None = recompute. Reset (_invalidate) by every change
        #: that decides who hears a frame: attach/detach, (dis)connect, error state, bit timing.
        self._receivers: _Audience | None = None
        #: Per frame kind (_route_key) the receivers of the audience that take such a frame and
        #: their callbacks, built on first use; a new dict when the audience or a callback changes.
        self._routes: dict[int, _Route] = {}
        #: Frames / bytes delivered in the present audience epoch (all, and those that were FD):
        #: receive counters are settled from these (_settle_rx) instead of per receiver and frame.
        self._ep_frames = 0
        self._ep_bytes = 0
        self._ep_fd_frames = 0
        self._ep_fd_bytes = 0
        self.stats = BusStats(since=clock.now())
        self._monitors: list[FrameCallback] = []
        self._in_flight: _InFlight | None = None
        self._arb_timer: TimerHandle | None = None
        self._idle_at = clock.now()
        self._drop_next = 0
        self._corrupt_next = 0
        self._load: _Load | None = None
        #: True while _end_of_frame delivers (with timing): kicks are deferred to its arbitration
        self._ending = False
        self._kick_deferred = False
        #: (bit rate, durations of classic base data frames with 0..8 bytes) for that bit rate
        self._classic_durations: tuple[int, tuple[float, ...]] | None = None
        #: The end of the frame on the wire (one at a time): one handle, queued again per frame.
        self._eof_handle = TimerHandle(0.0, 0, self._end_of_frame, ())
        #: The arbitration a sent frame asks for (_kick): one handle, queued again per kick.
        self._arb_handle = TimerHandle(0.0, 0, self._arbitrate, ())

    def __repr__(self) -> str:
        fd = f"/{self.data_bitrate}" if self.data_bitrate else ""
        return f"<VirtualBus {self.name} {self.bitrate}{fd} bit/s, {len(self.controllers)} controllers>"

    @property
    def is_fd(self) -> bool:
        return self._data_bitrate is not None

    @property
    def bitrate(self) -> int:
        return self._bitrate

    @bitrate.setter
    def bitrate(self, value: int) -> None:
        """Re-time the whole segment (e.g. after an LSS bit-timing switch); controllers re-check."""
        self._bitrate = value
        for c in self.controllers:
            c._check_timing()

    @property
    def data_bitrate(self) -> int | None:
        return self._data_bitrate

    @data_bitrate.setter
    def data_bitrate(self, value: int | None) -> None:
        self._data_bitrate = value
        for c in self.controllers:
            c._check_timing()

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
        ctrl._check_timing()
        return ctrl

    def detach(self, ctrl: Controller) -> None:
        if ctrl in self.controllers:
            self.controllers.remove(ctrl)
            ctrl.connected = False
            self._invalidate()
            ctrl.tx_queue.clear()

    def add_monitor(self, callback: FrameCallback) -> None:
        """Call ``callback(frame, t)`` for every frame that completes on the bus (for traces)."""
        self._monitors.append(callback)

    def remove_monitor(self, callback: FrameCallback) -> None:
        if callback in self._monitors:
            self._monitors.remove(callback)

    @property
    def busy(self) -> bool:
        """True while a frame is on the wire or any connected controller has one queued."""
        return self.is_busy()

    def is_busy(self) -> bool:
        """:attr:`busy` as a method (a cheap condition for ``clock.run_while``)."""
        if self._in_flight is not None or self._arb_timer is not None:
            return True
        for c in self.controllers:
            if (c.tx_queue and c._connected and c.state is not _BUS_OFF and c.timing_matches
                    and not c.synthetic):
                return True
        return False

    # -- fault injection ---------------------------------------------------------------------
    def disconnect(self, ctrl: Controller) -> None:
        """Unplug a controller: it neither sends nor receives; its queue waits for reconnect."""
        ctrl.connected = False

    def reconnect(self, ctrl: Controller) -> None:
        ctrl.connected = True
        if ctrl.tx_queue:
            self._kick()

    def force_bus_off(self, ctrl: Controller) -> None:
        ctrl.tec = 256
        ctrl._update_state()

    def drop_next(self, n: int = 1) -> None:
        """The next ``n`` frames vanish: the sender sees success, nobody receives them."""
        self._drop_next += n

    def corrupt_next(self, n: int = 1) -> None:
        """The next ``n`` frames arrive corrupted: CRC error frame, counters, retransmission."""
        self._corrupt_next += n

    def set_load(self, percent: float, can_id: int = 0x7FF, length: int = 8) -> None:
        """Add synthetic bus load from a phantom node sending ``can_id`` (0 disables)."""
        if self._load is not None:
            if self._load.timer is not None:
                self._load.timer.cancel()
            if self._load.controller is not None:
                self.detach(self._load.controller)
            self._load = None
        if percent <= 0:
            return
        if percent >= 100:
            raise ConfigError("synthetic load must be below 100 %")
        frame = CanFrame(can_id, bytes(length))
        load = _Load(percent, frame)
        ctrl = self.attach("<load>", auto_recover=True)
        self._invalidate()
        ctrl.synthetic = True
        load.controller = ctrl
        self._load = load
        self._load_tick()

    def _load_tick(self) -> None:
        load = self._load
        if load is None or load.controller is None:
            return
        if not load.controller.tx_queue:
            load.controller.send(load.frame)
        period = frame_duration(load.frame, self.bitrate) * 100.0 / load.percent
        load.timer = self.clock.call_later(period, self._load_tick)

    # -- statistics --------------------------------------------------------------------------
    def load_percent(self) -> float:
        """Share of time the bus was busy since the statistics were reset."""
        elapsed = self.clock.now() - self.stats.since
        return 100.0 * self.stats.busy_time / elapsed if elapsed > 0 else 0.0

    def reset_stats(self) -> None:
        self.stats = BusStats(since=self.clock.now())
        self._settle_rx()
        for c in self.controllers:
            c._stats = ControllerStats()

    # -- the arbitration engine --------------------------------------------------------------
    def _kick(self) -> None:
        if self._in_flight is None and self._arb_timer is None:
            if self._ending:
                # a frame sent while a completed frame is being delivered: _end_of_frame
                # arbitrates right after the delivery, at this same instant
                self._kick_deferred = True
                return
            clock = self.clock
            now = clock.now()
            idle_at = self._idle_at
            # call_at(max(now, idle_at), self._arbitrate) with the bus's own handle: it is
            # never cancelled, so it can be queued again however many runs of it are pending
            handle = self._arb_handle
            clock.reschedule(handle, idle_at if idle_at > now else now)
            self._arb_timer = handle

    def _arbitrate(self, start: float | None = None) -> None:
        """Start the next frame at ``start`` (default now): in real time a late wake-up must not
        stretch the frame schedule, so back-to-back frames start at the previous frame's end."""
        self._arb_timer = None
        if self._in_flight is not None:
            return
        now = self.clock.now() if start is None else start
        while True:
            audience = self._receivers
            if audience is None:
                audience = self._audience()
            best: Controller | None = None
            best_key = 0
            wait_until: float | None = None
            # the audience's senders: connected, not bus-off, matching bit timing
            for c in audience.senders:
                queue = c.tx_queue
                if not queue:
                    continue
                if c._ready_at > now:
                    wait_until = c._ready_at if wait_until is None else min(wait_until, c._ready_at)
                    continue
                head = queue[0]
                # arbitration_key(), inlined for base frames (the hot path)
                key = arbitration_key(head) if head.extended else (head.can_id << 21) | (head.rtr << 20)
                if best is None or key < best_key:
                    best, best_key = c, key
            if best is None:
                if wait_until is not None:
                    self._arb_timer = self.clock.call_at(wait_until, self._arbitrate)
                return
            frame = best.tx_queue[0]
            if best.synthetic:
                outcome = "ok"
            elif self._drop_next:
                self._drop_next -= 1
                outcome = "drop"
            elif self._corrupt_next:
                self._corrupt_next -= 1
                outcome = "crc"
            elif frame.fd:
                outcome = "ok" if self._acknowledged(best, frame) else "ack"
            else:   # _acknowledged for a classic frame: anyone but the sender acknowledges
                sole = audience.sole_ack
                outcome = "ok" if audience.many_acks or (sole is not None and sole is not best) else "ack"
            if not self.timing:
                duration = 0.0
            elif outcome == "ok" or outcome == "drop":
                if frame.fd or frame.extended:
                    duration = frame_duration(frame, self.bitrate, self.data_bitrate)
                else:
                    durations = self._classic_durations
                    if durations is None or durations[0] != self._bitrate:
                        durations = self._classic_durations = (
                            self._bitrate, tuple(frame_duration(CanFrame(0, bytes(n)), self._bitrate)
                                                 for n in range(9)))
                    duration = durations[1][0 if frame.rtr else len(frame.data)]
            else:
                bits = ERROR_FRAME_BITS + (SUSPEND_TRANSMISSION_BITS if best.state is ErrorState.ERROR_PASSIVE else 0)
                if frame.fd and frame.brs and self.data_bitrate:
                    until_ack = frame_duration(frame, self.bitrate, self.data_bitrate) - 12 / self.bitrate
                else:
                    until_ack = frame_bits_until_ack(frame) / self.bitrate
                duration = until_ack + bits / self.bitrate
            end = now + duration
            if duration:
                self._in_flight = (best, frame, outcome, now, end)
                self.clock.reschedule(self._eof_handle, end)
                return
            # no frame timing: the frame ends at once (what _end_of_frame does), then the next
            # arbitration at the same instant (a loop instead of the recursion through _end_of_frame)
            self._complete((best, frame, outcome, now, end), False)
            self._arb_timer = None
            if self._in_flight is not None:
                return
            now = end

    def _acknowledged(self, sender: Controller, frame: CanFrame) -> bool:
        # the cached audience: connected, not bus-off, not synthetic, matching bit timing
        audience = self._receivers
        acks = (audience if audience is not None else self._audience()).acks
        if not frame.fd:
            n = len(acks)
            return n > 1 or (n == 1 and acks[0] is not sender)
        return any(c is not sender and c.fd for c in acks)

    def _end_of_frame(self) -> None:
        flight = self._in_flight
        assert flight is not None
        self._in_flight = None
        if not self.timing:
            self._complete(flight, True)
            return
        # With frame timing the next frame after this one always takes time on the wire, so an
        # arbitration timer that a frame sent during the delivery would schedule for this instant
        # could only find the bus busy: it is scheduled only when no frame follows at once.
        self._ending = True
        try:
            self._complete(flight, False)
        except BaseException:
            self._ending = False
            if self._kick_deferred:
                self._kick_deferred = False
                self._kick()
            raise
        self._ending = False
        self._arbitrate(flight[4])
        if self._kick_deferred:
            self._kick_deferred = False
            if self._in_flight is None:
                clock = self.clock
                clock.call_at(max(clock.now(), self._idle_at), self._arbitrate)

    def _complete(self, flight: _InFlight, arbitrate: bool) -> None:
        """Account for a finished frame (delivery, counters, retransmission), then arbitrate the
        next one if ``arbitrate`` (else ``_end_of_frame`` does it)."""
        sender, frame, outcome, start, now = flight
        self._idle_at = now
        stats = self.stats
        since = stats.since
        stats.busy_time += now - (since if since > start else start)   # max(start, since)
        queue = sender.tx_queue
        if outcome == "ok" and queue and queue[0] is frame:
            # the common case first: a frame sent and acknowledged (same steps as below)
            queue.popleft()
            n = len(frame.data)
            st = sender._stats
            st.tx_frames += 1
            st.tx_bytes += n
            if sender.tec:
                sender.tec -= 1
                if sender.state is not ErrorState.ERROR_ACTIVE:
                    sender._update_state()
            stats.frames += 1
            stats.bytes += n
            audience = self._receivers
            if (audience is None or not audience.plain or frame.fd or frame.extended or sender.receive_own
                    or self._monitors):
                self._deliver(sender, frame, now)
            else:
                # _deliver for a classic base frame on a bus without listeners to every frame,
                # written out: count it for the epoch, call the route of its identifier
                self._ep_frames += 1
                self._ep_bytes += n
                sender._own_frames += 1
                sender._own_bytes += n
                routes = self._routes
                route = routes.get(frame.can_id)
                if route is None:
                    route = self._route(frame)
                    routes = self._routes
                for c, cb, i in route:
                    if c is not sender:
                        cb(frame, now)
                        if self._routes is not routes:
                            self._deliver_each(sender, frame, now, audience.hear, i + 1)
                            break
            if sender.on_event is not None:
                sender.on_event(TxDoneEvent(frame, now))
            if arbitrate:
                self._arbitrate(now)
            return
        if sender.tx_queue and sender.tx_queue[0] is frame:
            pass
        elif outcome in ("ok", "drop"):
            outcome = "detached"  # the sender was detached mid-frame: the frame completes for nobody
        if outcome == "detached":
            pass
        elif outcome == "ok" or outcome == "drop":
            sender.tx_queue.popleft()
            n = len(frame.data)
            st = sender._stats
            st.tx_frames += 1
            st.tx_bytes += n
            if sender.tec:
                sender.tec -= 1
                if sender.state is not ErrorState.ERROR_ACTIVE:
                    sender._update_state()
            if outcome == "ok":
                stats.frames += 1
                stats.bytes += n
                self._deliver(sender, frame, now)
            else:
                stats.dropped_frames += 1
            if sender.on_event is not None:
                sender.on_event(TxDoneEvent(frame, now))
        else:
            stats.error_frames += 1
            kind = ErrorKind.ACK if outcome == "ack" else ErrorKind.CRC
            sender._stats.tx_retransmissions += 1
            sender._error(kind, True, frame, now)
            sender._ready_at = now
            if kind is ErrorKind.CRC:
                for c in self.controllers:
                    if (c is not sender and c.connected and c.state is not ErrorState.BUS_OFF
                            and c.timing_matches and not c.synthetic):
                        c._error(kind, False, frame, now)
            if sender.state is not ErrorState.BUS_OFF and not sender.auto_retransmit and sender.tx_queue:
                sender.tx_queue.popleft()
                sender._emit(TxAbortedEvent(frame, now, "single-shot"))
            self._foreign_errors(now)
        if outcome == "drop":
            self._foreign_errors(now)
        if arbitrate:
            self._arbitrate(now)

    def _audience(self) -> _Audience:
        """Who takes part in the next frames (see :class:`_Audience`), cached until something
        changes it. Building it starts a new epoch of receive counting."""
        audience = self._receivers
        if audience is None:
            audience = _Audience(self.controllers)
            for c in audience.hear:
                c._own_frames = c._own_bytes = 0
            self._ep_frames = self._ep_bytes = self._ep_fd_frames = self._ep_fd_bytes = 0
            self._receivers = audience
            self._routes = {}
        return audience

    def _invalidate(self) -> None:
        """Who hears frames may change: settle the receive counters of the present audience,
        forget it and the routes."""
        if self._receivers is not None:
            self._settle_rx()
            self._receivers = None
        self._routes = {}

    def _settle_rx(self) -> None:
        """Add the frames delivered in this audience epoch to each receiver's counters (all
        frames to an FD controller, the classic ones to the others, never its own)."""
        audience = self._receivers
        frames = self._ep_frames
        if audience is None or not frames:
            return
        nbytes = self._ep_bytes
        fd_frames, fd_bytes = self._ep_fd_frames, self._ep_fd_bytes
        for c in audience.hear:
            st = c._stats
            if c._fd:
                st.rx_frames += frames - c._own_frames
                st.rx_bytes += nbytes - c._own_bytes
            else:
                st.rx_frames += frames - fd_frames - c._own_frames
                st.rx_bytes += nbytes - fd_bytes - c._own_bytes
            c._own_frames = c._own_bytes = 0
        self._ep_frames = self._ep_bytes = self._ep_fd_frames = self._ep_fd_bytes = 0

    def _route(self, frame: CanFrame) -> _Route:
        """The receivers (in audience order, with their place in it) that get a callback for a
        frame of this kind, and that callback; cached per _route_key."""
        receivers = self._audience().hear
        fd = frame.fd
        can_id = -1 if frame.extended else frame.can_id
        route = []
        for i, c in enumerate(receivers):
            if fd and not c._fd:
                continue
            table = c._rx_table
            cb = c._on_frame if table is None else table.get(can_id)
            if cb is not None:
                route.append((c, cb, i))
        found = tuple(route)
        self._routes[_route_key(frame)] = found
        return found

    def _deliver(self, sender: Controller, frame: CanFrame, now: float) -> None:
        audience = self._receivers
        if audience is None:
            audience = self._audience()
        n = len(frame.data)
        self._ep_frames += 1
        self._ep_bytes += n
        fd = frame.fd
        if fd:
            self._ep_fd_frames += 1
            self._ep_fd_bytes += n
        sender._own_frames += 1
        sender._own_bytes += n
        if sender.receive_own and sender._on_frame is not None:
            sender._on_frame(frame, now)
        if audience.eager:
            self._deliver_each(sender, frame, now, audience.hear, 0)
        else:
            routes = self._routes
            key = frame.can_id if not (fd or frame.extended) else _route_key(frame)
            route = routes.get(key)
            if route is None:
                route = self._route(frame)
                routes = self._routes
            for c, cb, i in route:
                if c is not sender:
                    cb(frame, now)
                    if self._routes is not routes:
                        # a callback changed the audience or a callback: the rest of this
                        # frame's receivers are served one by one, as they are now
                        self._deliver_each(sender, frame, now, audience.hear, i + 1)
                        break
        for c in audience.foreign:
            c._error(ErrorKind.FORM, False, None, now)  # a foreign bit rate sees only garbage
        for monitor in self._monitors:
            monitor(frame, now)

    def _deliver_each(self, sender: Controller, frame: CanFrame, now: float,
                      receivers: list[Controller], first: int) -> None:
        """Delivery to ``receivers[first:]`` one by one: a receiver with REC > 0 counts it down
        (ISO 11898-1 fault confinement) before its callback runs."""
        fd = frame.fd
        can_id = -1 if frame.extended else frame.can_id
        cleared = False
        for c in receivers[first:]:
            if c is sender or (fd and not c._fd):
                continue
            if c.rec:
                c.rec = c.rec - 1 if c.rec <= 127 else 120
                cleared = cleared or not c.rec
                if c.state is not ErrorState.ERROR_ACTIVE:
                    c._update_state()
            table = c._rx_table
            cb = c._on_frame if table is None else table.get(can_id)
            if cb is not None:
                cb(frame, now)
        audience = self._receivers
        if cleared and audience is not None and not any(c.rec for c in audience.hear):
            self._invalidate()   # nobody counts down any more: back to the routes

    def _foreign_errors(self, now: float) -> None:
        """Controllers at another bit rate see every frame as a form error (and nothing else)."""
        for c in self._audience().foreign:
            c._error(ErrorKind.FORM, False, None, now)
