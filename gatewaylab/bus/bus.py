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

from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.timing import (
    BUS_OFF_RECOVERY_BITS,
    ERROR_FRAME_BITS,
    arbitration_key,
    classic_durations,
    error_duration,
    frame_duration,
)
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import ConfigError, FrameError, LocalError


class ErrorState(Enum):
    """Fault-confinement state of a controller (CAN 2.0 §8 'Fault Confinement', carried into ISO 11898-1)."""

    ERROR_ACTIVE = "error-active"
    ERROR_PASSIVE = "error-passive"
    BUS_OFF = "bus-off"


#: Enum members as module constants for the per-frame paths (attribute access on an Enum class
#: costs about 80 ns in Python 3.11, a global about 10 ns).
_BUS_OFF = ErrorState.BUS_OFF
_ACTIVE = ErrorState.ERROR_ACTIVE


class ErrorKind(Enum):
    """Why an error frame was sent."""

    ACK = "ack"          # nobody acknowledged the frame
    CRC = "crc"          # a receiver saw a corrupted frame (fault injection)
    BIT = "bit"          # the controller's bit timing does not match the bus
    FORM = "form"        # a frame sent at a foreign bit rate, seen as garbage
    STUFF = "stuff"      # more than five equal bits in a row: a bus held dominant (fault injection)


class Outcome(Enum):
    """How a transmission ends: what its sender and its receivers see."""

    SENT = "sent"            # acknowledged: every receiver gets the frame at its end
    DROPPED = "dropped"      # fault injection: the sender sees success, nobody receives the frame
    ACK_ERROR = "ack"        # nobody acknowledged: an error frame, the sender retransmits
    CRC_ERROR = "crc"        # fault injection: the receivers see a CRC error, the sender retransmits


#: Frames that take no time (a bus without frame timing) end at once, at most this many in a
#: row; then the bus goes on in a new clock event (see VirtualBus._arbitrate).
ZERO_TIME_BURST = 32

_SENT = Outcome.SENT
_DROPPED = Outcome.DROPPED
_ACK_ERROR = Outcome.ACK_ERROR
_CRC_ERROR = Outcome.CRC_ERROR


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
    #: times the controller went bus-off (a short bus-off with auto-recovery leaves only this trace)
    bus_offs: int = 0


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
        self.synthetic = False
        self._recovery: TimerHandle | None = None
        self._mismatch_timer: TimerHandle | None = None
        #: The frame at the head of tx_queue when the bus last arbitrated, and its arbitration
        #: key: computed once per frame, not in every arbitration the frame waits through.
        self._head: CanFrame | None = None
        self._head_key = 0

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
        self.bus._invalidate()
        self._on_frame = value

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
        self.bus._invalidate()
        self._rx_table = None if value is None else dict(value)

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
            self.bus._kick()
        elif self._mismatch_timer is None:
            self._mismatch_timer = self.bus.clock.call_soon(self._mismatch_attempt)

    def flush_tx(self) -> None:
        self.tx_queue.clear()

    # -- transmit queue editing (one way in for devices: M_CAN TX queue, cancellation) ----------
    def withdraw(self, frame: CanFrame) -> bool:
        """Take a queued frame (this very object) back before it is sent, as a TX buffer
        cancellation request does (M_CAN TXBCR); False when it is on the wire now (it completes)
        or not queued here."""
        on_wire = self.bus.on_wire
        busy = on_wire.frame if on_wire is not None and on_wire.sender is self else None
        queue = self.tx_queue
        for i, queued in enumerate(queue):
            if queued is frame:
                if queued is busy:
                    return False
                del queue[i]
                return True
        return False

    def send_by_priority(self, frame: CanFrame) -> None:
        """:meth:`send` in priority order, for a controller whose transmit queue picks the highest
        arbitration priority first (M_CAN TX queue mode, TXBC.TFQM = 1): the frame goes behind the
        queued frames with a lower or equal arbitration key, never before the one on the wire."""
        self.send(frame)
        queue = self.tx_queue
        on_wire = self.bus.on_wire
        start = 1 if on_wire is not None and on_wire.sender is self else 0
        key = arbitration_key(frame)
        pos = len(queue) - 1
        while pos > start and arbitration_key(queue[pos - 1]) > key:
            pos -= 1
        if pos != len(queue) - 1:
            queue.pop()
            queue.insert(pos, frame)

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
            self._stats.bus_offs += 1
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

    def _received(self) -> None:
        """A frame received without error counts REC down (CAN 2.0 §8 rule 8: from above 127 to
        a value between 119 and 127; 120 here)."""
        self.rec = self.rec - 1 if self.rec <= 127 else 120
        if self.state is not _ACTIVE:
            self._update_state()

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
                    # from now on it counts REC down with every frame it receives: the routes
                    # of the bus's audience must name it for every frame
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


@dataclass(frozen=True, slots=True)
class Transmission:
    """What one arbitration puts on the wire: the winning frame, how it ends, from when to when
    (:meth:`VirtualBus._next_transmission`)."""

    sender: Controller
    frame: CanFrame
    outcome: Outcome
    start: float
    end: float


#: :class:`Transmission` as the plain tuple ``(sender, frame, outcome, start, end)`` the bus's
#: engine passes from arbitration to end of frame: built and unpacked once per frame, a tuple
#: costs a fraction of a class instance (a record instance per frame: 3 % of the drive benchmark).
_Step = tuple[Controller, CanFrame, Outcome, float, float]


class _RxCounters:
    """Receive counters of one audience. Every hearing controller receives every delivered frame
    but its own (and no FD frame when it is not FD capable), so the bus tallies each frame once,
    per sender, and adds each receiver's share to its stats when the audience ends or stats are
    read (settle)."""

    __slots__ = ("sent",)

    def __init__(self) -> None:
        #: per sender: [frames, bytes, FD frames, FD bytes] delivered since the last settle
        self.sent: dict[Controller, list[int]] = {}

    def count(self, sender: Controller, frame: CanFrame) -> None:
        """One delivered frame."""
        try:
            tally = self.sent[sender]
        except KeyError:
            tally = self.sent[sender] = [0, 0, 0, 0]
        n = len(frame.data)
        tally[0] += 1
        tally[1] += n
        if frame.fd:
            tally[2] += 1
            tally[3] += n

    def settle(self, receivers: list[Controller]) -> None:
        """Add what each receiver got since the last settle to its stats; start again from zero."""
        sent = self.sent
        if not sent:
            return
        frames, nbytes, fd_frames, fd_bytes = (sum(column) for column in zip(*sent.values()))
        for c in receivers:
            own = sent.get(c, (0, 0, 0, 0))
            st = c._stats
            if c._fd:
                st.rx_frames += frames - own[0]
                st.rx_bytes += nbytes - own[1]
            else:   # its own frames are classic ones
                st.rx_frames += frames - fd_frames - own[0]
                st.rx_bytes += nbytes - fd_bytes - own[1]
        sent.clear()


#: the receivers of one kind of frame, each with its callback (None: it only counts REC down)
_Route = tuple[tuple[Controller, FrameCallback | None], ...]


class _Routes(dict[int, _Route]):
    """The receivers of each kind of frame (see :data:`_Route`), built when a kind is first
    asked for. Frames of one kind reach the same receivers: classic base frames by identifier,
    FD base frames by identifier + 0x800 (a range of their own), extended frames by format only
    (-1 classic, -2 FD); VirtualBus._deliver computes that key, the one place that does."""

    __slots__ = ("hear",)

    def __init__(self, hear: list[Controller]) -> None:
        super().__init__()
        self.hear = hear

    def __missing__(self, key: int) -> _Route:
        """The route of a kind not seen since the audience was built: the receivers in
        attachment order, each with the callback it gets the frame through; receivers with
        REC > 0 are named even without a callback."""
        fd = key == -2 or key >= 0x800
        can_id = key - 0x800 if key >= 0x800 else key
        entries = []
        for c in self.hear:
            if fd and not c._fd:
                continue
            table = c._rx_table
            cb = c._on_frame if table is None else table.get(can_id)   # no extended ids in tables
            if cb is not None or c.rec:
                entries.append((c, cb))
        route = self[key] = tuple(entries)
        return route


class _Audience:
    """Who takes part in frames while nothing changes on the bus, their callbacks per kind of
    frame, and what they received. The bus builds it on demand; VirtualBus._invalidate (the one
    invalidation point) settles its receive counters and drops it."""

    __slots__ = ("acks", "fd_acks", "foreign", "hear", "routes", "rx", "senders")

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
        #: those of them that acknowledge FD frames
        self.fd_acks = [c for c in self.acks if c._fd]
        self.routes = _Routes(self.hear)
        self.rx = _RxCounters()


class _FaultPlan:
    """Faults planned for the next transmissions: frames to drop or corrupt (any, or of one
    CAN id) and a span of noise. The bus asks it for the outcome of each transmission while it
    exists (``outcome``, which changes nothing) and tells it each transmission put on the wire
    (``commit``, which consumes what was used); when it is spent the bus forgets it."""

    __slots__ = ("corrupt", "drop", "errors_every", "errors_seen", "errors_until")

    def __init__(self) -> None:
        #: [can_id or None (any frame), frames left], in the order they were asked for
        self.drop: list[list[int | None]] = []
        self.corrupt: list[list[int | None]] = []
        self.errors_until = float("-inf")
        self.errors_every = 1
        self.errors_seen = 0

    @staticmethod
    def add(rules: list[list[int | None]], n: int, can_id: int | None) -> None:
        if n < 1:
            raise LocalError(f"the number of frames must be >= 1, got {n}")
        for rule in rules:
            if rule[0] == can_id:
                rule[1] = (rule[1] or 0) + n
                return
        rules.append([can_id, n])

    @staticmethod
    def _match(rules: list[list[int | None]], frame: CanFrame) -> list[int | None] | None:
        for rule in rules:
            if rule[0] is None or rule[0] == frame.can_id:
                return rule
        return None

    def outcome(self, frame: CanFrame, start: float) -> Outcome | None:
        """DROPPED or CRC_ERROR when a planned fault hits this frame; None: no fault."""
        if self.drop and self._match(self.drop, frame) is not None:
            return _DROPPED
        if self.corrupt and self._match(self.corrupt, frame) is not None:
            return _CRC_ERROR
        if start < self.errors_until and self.errors_seen % self.errors_every == 0:
            return _CRC_ERROR
        return None

    def commit(self, step: _Step) -> bool:
        """Consume what hit the transmission ``step`` (the same choice :meth:`outcome` made); True when spent."""
        sender, frame, outcome, start, _ = step
        if outcome is _DROPPED:
            rules = self.drop
        elif outcome is _CRC_ERROR and self._match(self.corrupt, frame) is not None:
            rules = self.corrupt
        else:
            rules = None
        if rules is not None:
            rule = self._match(rules, frame)
            assert rule is not None and rule[1] is not None
            rule[1] -= 1
            if not rule[1]:
                rules.remove(rule)
        elif not sender.synthetic and start < self.errors_until:
            self.errors_seen += 1
        return not self.drop and not self.corrupt and start >= self.errors_until


class _Jam:
    """A bus held dominant: until when, who counts as transmitter, the steps of rule 6."""

    __slots__ = ("bus_off", "release", "start", "step", "transmitters", "until", "wire")

    def __init__(self, start: float, until: float, wire: _Step) -> None:
        self.start = start
        self.until = until
        self.wire = wire
        self.transmitters: list[Controller] = []
        self.bus_off: list[Controller] = []
        self.release = TimerHandle(until, 0, lambda: None, ())
        self.step = TimerHandle(start, 0, lambda: None, ())


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
        #: durations of classic base frames with 0..8 data bytes at the bit rate
        self._classic_times = classic_durations(bitrate)
        #: False: frames take no time (ordering and arbitration still apply). For load tests.
        self.timing = timing
        self.controllers: list[Controller] = []
        #: Cached audience (see _audience); None = build again. Dropped by _invalidate whenever
        #: something changes who hears, acknowledges or sends a frame, or through which callback.
        self._receivers: _Audience | None = None
        self.stats = BusStats(since=clock.now())
        self._monitors: list[FrameCallback] = []
        #: The transmission on the wire, until its end of frame has been handled.
        self._on_wire: _Step | None = None
        #: The pending arbitration a queued frame asked for (see _kick).
        self._arb_timer: TimerHandle | None = None
        self._idle_at = clock.now()
        #: Faults planned for the next transmissions (docs/bus.md); None costs the hot path one test.
        self._faults: _FaultPlan | None = None
        #: A bus held dominant (stuck_dominant), until it is released.
        self._jam: _Jam | None = None
        self._load: _Load | None = None
        #: One end of frame and one arbitration are pending at most: each has one handle that
        #: the bus queues again (clock.reschedule) instead of a new handle per frame.
        self._eof_handle = TimerHandle(0.0, 0, self._end_of_frame, ())
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
        self._classic_times = classic_durations(value)
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
        if self._on_wire is not None or self._arb_timer is not None:
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

    def drop_next(self, n: int = 1, can_id: int | None = None) -> None:
        """The next ``n`` frames (of ``can_id`` only, if given) vanish: the sender sees success,
        nobody receives them."""
        self._plan().add(self._plan().drop, n, can_id)

    def corrupt_next(self, n: int = 1, can_id: int | None = None) -> None:
        """The next ``n`` frames (of ``can_id`` only, if given) arrive corrupted: CRC error
        frame, counters, retransmission (a retransmission is a frame of its own)."""
        self._plan().add(self._plan().corrupt, n, can_id)

    def error_frames(self, duration: float, every: int = 1) -> None:
        """Noise for ``duration`` seconds: one frame in ``every`` that starts in that span ends
        in an error frame (a CRC error to its receivers: transmitter TEC + 8, receivers REC + 1,
        retransmission), as electromagnetic disturbance does (CAN 2.0 §8 rules 1 and 3)."""
        if duration <= 0 or every < 1:
            raise LocalError("error_frames: duration must be > 0 and every >= 1")
        plan = self._plan()
        plan.errors_until = max(plan.errors_until, self.clock.now() + duration)
        plan.errors_every = every
        plan.errors_seen = 0

    def force_error_passive(self, ctrl: Controller) -> None:
        """Put a controller's TEC at 128 (error-passive, CAN 2.0 §8 rule 9); every successful
        transmission then counts it down by one, so it is error-active again after its next one
        (rule 7), as a node that just had a burst of errors."""
        if ctrl.state is _BUS_OFF:
            raise LocalError(f"{ctrl.name}: controller is bus-off")
        ctrl.tec = max(ctrl.tec, 128)
        ctrl._update_state()

    def stuck_dominant(self, duration: float) -> None:
        """Hold the bus dominant for ``duration`` seconds (a jammed transceiver, CANH shorted to
        supply): no frame completes. The frame on the wire is destroyed; every controller that
        has a frame to send is a transmitter and every other one a receiver, and after the first
        error (TEC + 8, REC + 1) each counts + 8 per 8 more dominant bits (CAN 2.0 §8 rule 6),
        so transmitters go bus-off and receivers error-passive. Released, the bus is idle again:
        bus-off controllers recover after 128 x 11 recessive bits, queued frames go out."""
        if duration <= 0:
            raise LocalError("stuck_dominant: duration must be > 0")
        now = self.clock.now()
        jam = self._jam
        if jam is not None:
            jam.until = max(jam.until, now + duration)
            jam.release.cancel()
            jam.release = self.clock.call_at(jam.until, self._release_jam)
            return
        tx = self._on_wire
        sentinel = Controller(self, "<stuck dominant>", self.bitrate, None, False, False, False, False,
                              False, None, None)
        jam = self._jam = _Jam(now, now + duration, (sentinel, CanFrame(0), _ACK_ERROR, now, now))
        # a cancelled handle stays in the clock's queue: the bus takes fresh ones, so that a later
        # reschedule of the same handle cannot revive the stale entry
        if tx is not None:
            self._eof_handle.cancel()
            self._eof_handle = TimerHandle(0.0, 0, self._end_of_frame, ())
            jam.transmitters.append(tx[0])
            self.stats.busy_time += now - max(tx[3], self.stats.since)
        if self._arb_timer is not None:
            self._arb_timer.cancel()
            self._arb_timer = None
            self._arb_handle = TimerHandle(0.0, 0, self._arbitrate, ())
        self._on_wire = jam.wire        # the bus is busy: nothing arbitrates until the release
        jam.release = self.clock.call_at(jam.until, self._release_jam)
        # the first error: a bit error for the transmitter, a stuff error after 6 dominant bits
        jam.step = self.clock.call_later(6 / self.bitrate, self._jam_step, True)

    @property
    def stuck(self) -> bool:
        """True while the bus is held dominant (:meth:`stuck_dominant`)."""
        return self._jam is not None

    def _plan(self) -> _FaultPlan:
        plan = self._faults
        if plan is None:
            plan = self._faults = _FaultPlan()
        return plan

    def _jam_step(self, first: bool) -> None:
        """One step of CAN 2.0 §8 rule 6 on a bus held dominant: + 8 per 8 dominant bits."""
        jam = self._jam
        if jam is None:
            return
        now = self.clock.now()
        counting = False
        self.stats.error_frames += 1
        for c in list(self.controllers):
            if not c._connected or c.state is _BUS_OFF or c.synthetic:
                continue
            if c._listen_only:     # sees the error, never counts it (docs/bus.md)
                if first:
                    c._stats.error_frames += 1
                    c._emit(ErrorFrameEvent(ErrorKind.STUFF, now, False, None))
                continue
            if c.tx_queue or c in jam.transmitters:
                if c not in jam.transmitters:
                    jam.transmitters.append(c)
                c.tec += 8
                c._stats.error_frames += 1
                c._emit(ErrorFrameEvent(ErrorKind.BIT, now, True, c.tx_queue[0] if c.tx_queue else None))
                c._update_state()
                if c.state is _BUS_OFF:
                    if c._recovery is not None:   # recovery needs recessive bits: after the release
                        c._recovery.cancel()
                        c._recovery = None
                    jam.bus_off.append(c)
                else:
                    counting = True
            elif c.rec <= 127:
                c.rec = min(255, c.rec + (1 if first else 8))
                c._stats.error_frames += 1
                c._emit(ErrorFrameEvent(ErrorKind.STUFF, now, False, None))
                if c.rec == 1 and c.timing_matches:
                    self._invalidate()
                c._update_state()
                counting = counting or c.rec <= 127
        # after the first error flag (6 bits) the 14th dominant bit, then every 8 bits; once every
        # counter has settled only a node that queues a frame later can change: look each ms
        delay = (14 if first else 8) / self.bitrate if counting else 0.001
        jam.step = self.clock.call_later(delay, self._jam_step, False)

    def _release_jam(self) -> None:
        jam = self._jam
        if jam is None:
            return
        self._jam = None
        jam.step.cancel()
        now = self.clock.now()
        self.stats.busy_time += now - max(jam.start, self.stats.since)
        self._idle_at = now
        self._on_wire = None
        for c in jam.bus_off:
            if c.state is _BUS_OFF and c.auto_recover and c._recovery is None:
                c._recovery = self.clock.call_later(BUS_OFF_RECOVERY_BITS / self.bitrate, c.recover)
        for c in self.controllers:
            if c.tx_queue and c._connected:
                self._kick()
                break

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
        ctrl.synthetic = True
        self._invalidate()
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

    # -- who takes part ----------------------------------------------------------------------
    def _audience(self) -> _Audience:
        """Who takes part in the next frames (see :class:`_Audience`), cached until _invalidate."""
        audience = self._receivers
        if audience is None:
            audience = self._receivers = _Audience(self.controllers)
        return audience

    def _invalidate(self) -> None:
        """Who hears, acknowledges or sends frames, or through which callback, may change:
        settle the receive counters of the present audience and forget it."""
        audience = self._receivers
        if audience is not None:
            audience.rx.settle(audience.hear)
            self._receivers = None

    def _settle_rx(self) -> None:
        """Bring every controller's receive counters up to date (before they are read)."""
        audience = self._receivers
        if audience is not None:
            audience.rx.settle(audience.hear)

    # -- the arbitration engine --------------------------------------------------------------
    def _kick(self) -> None:
        """A frame is waiting: arbitrate as soon as the bus is idle. While a frame is on the wire
        nothing is scheduled: its end of frame arbitrates the next one."""
        if self._on_wire is None and self._arb_timer is None:
            clock = self.clock
            self._arb_timer = handle = self._arb_handle
            clock.reschedule(handle, max(clock.now(), self._idle_at))

    @property
    def on_wire(self) -> Transmission | None:
        """The transmission on the wire now (None when idle): who sends which frame, so a device can
        leave the frame it is sending alone when it edits its own transmit queue."""
        step = self._on_wire
        return None if step is None else Transmission(*step)

    def _next_transmission(self, start: float) -> Transmission | None:
        """The arbitration step: which queued frame wins at ``start`` (the lowest arbitration
        field), how its transmission ends and when. It reads the bus and changes nothing."""
        step = self._arbitration(start)
        return None if step is None else Transmission(*step)

    def _arbitration(self, start: float) -> _Step | None:
        """:meth:`_next_transmission` as the engine's tuple (the one implementation)."""
        audience = self._receivers or self._audience()
        sender: Controller | None = None
        best = 0
        for c in audience.senders:
            queue = c.tx_queue
            if queue:
                head = queue[0]
                if head is not c._head:
                    c._head = head
                    c._head_key = arbitration_key(head)
                key = c._head_key
                if sender is None or key < best:
                    sender, best = c, key
        if sender is None:
            return None
        frame = sender.tx_queue[0]
        # acknowledged when a controller other than the sender acknowledges (an FD frame: an FD one)
        acks = audience.fd_acks if frame.fd else audience.acks
        if sender.synthetic:
            outcome = _SENT
        elif self._faults is not None and (planned := self._faults.outcome(frame, start)) is not None:
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
            if self._faults is not None and self._faults.commit(step):
                self._faults = None
            self._on_wire = step
            if end != now:
                self.clock.reschedule(self._eof_handle, end)
                return
            burst += 1
            try:
                self._end_of_frame(False)
            except BaseException:
                self._kick()   # the frames still queued go on in a clock event of their own
                raise
            if burst == ZERO_TIME_BURST:
                self._kick()
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
                st = sender._stats
                st.tx_frames += 1
                st.tx_bytes += n
                if sender.tec:   # every success takes one off TEC (CAN 2.0 §8 rule 7)
                    sender.tec -= 1
                    if sender.state is not _ACTIVE:
                        sender._update_state()
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
            sender._stats.tx_retransmissions += 1
            sender._error(kind, True, frame, end)
            if kind is ErrorKind.CRC:
                for c in self._audience().hear:
                    if c is not sender:
                        c._error(kind, False, frame, end)
            if (not sender.auto_retransmit and sender.state is not _BUS_OFF
                    and queue and queue[0] is frame):
                queue.popleft()
                sender._emit(TxAbortedEvent(frame, end, "single-shot"))
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
        if sender.receive_own and sender._on_frame is not None:
            sender._on_frame(frame, now)
        # the kind of frame (see _Routes): its receivers are looked up, built on first use
        fd = frame.fd
        kind = (-2 if fd else -1) if frame.extended else (frame.can_id + 0x800 if fd else frame.can_id)
        for c, cb in audience.routes[kind]:
            if c is not sender:
                if c.rec:
                    c._received()
                if cb is not None:
                    cb(frame, now)
        if audience.foreign:     # (an empty loop still builds an iterator: once per frame)
            for c in audience.foreign:
                c._error(ErrorKind.FORM, False, None, now)  # a foreign bit rate sees only garbage
        if self._monitors:
            for monitor in self._monitors:
                monitor(frame, now)

    def _foreign_errors(self, now: float) -> None:
        """Controllers at another bit rate see every frame as a form error (and nothing else)."""
        for c in self._audience().foreign:
            c._error(ErrorKind.FORM, False, None, now)
