"""One CAN controller on a :class:`~gatewaylab.bus.bus.VirtualBus`: its transmit queue, its
ISO 11898-1 fault confinement (TEC/REC, error-active/passive, bus-off and recovery) and the
events it reports (error frames, state changes, transmissions done or aborted).

What the controller needs of its bus is :class:`ControllerBus` (three notices and a few readings);
what the bus and its fault injector do to a controller are the public methods under "the bus's
side" below (counting errors and receptions, re-deriving the state, recovery, events).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from types import MappingProxyType
from typing import TYPE_CHECKING, Final, Protocol

from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.stats import ControllerStats
from gatewaylab.bus.timing import BUS_OFF_RECOVERY_BITS, ERROR_FRAME_BITS, arbitration_key
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import FrameError, LocalError

if TYPE_CHECKING:
    from gatewaylab.bus.bus import VirtualBus
    from gatewaylab.bus.transmission import Transmission

__all__ = [
    "BusEvent", "Controller", "ControllerBus", "ErrorFrameEvent", "ErrorKind", "ErrorState", "EventCallback",
    "FrameCallback", "StateChangeEvent", "TxAbortedEvent", "TxDoneEvent",
]


class ErrorState(Enum):
    """Fault-confinement state of a controller (CAN 2.0 §8 'Fault Confinement', carried into ISO 11898-1)."""

    ERROR_ACTIVE = "error-active"
    ERROR_PASSIVE = "error-passive"
    BUS_OFF = "bus-off"


#: Enum members as module constants for the per-frame paths (attribute access on an Enum class
#: costs about 80 ns in Python 3.11, a global about 10 ns; ``Final``: compiled, a static instead of a
#: lookup in the module's dictionary on every frame).
_BUS_OFF: Final = ErrorState.BUS_OFF
_ACTIVE: Final = ErrorState.ERROR_ACTIVE


class ErrorKind(Enum):
    """Why an error frame was sent."""

    ACK = "ack"          # nobody acknowledged the frame
    CRC = "crc"          # a receiver saw a corrupted frame (fault injection)
    BIT = "bit"          # the controller's bit timing does not match the bus
    FORM = "form"        # a frame sent at a foreign bit rate, seen as garbage
    STUFF = "stuff"      # more than five equal bits in a row: a bus held dominant (fault injection)



@dataclass(frozen=True, slots=True)
class ErrorFrameEvent:
    """An error frame this controller took part in (as transmitter or receiver)."""

    kind: ErrorKind
    timestamp: float
    transmitter: bool
    frame: CanFrame | None


@dataclass(frozen=True, slots=True)
class StateChangeEvent:
    """The controller changed fault-confinement state (with the counters that made it)."""
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


class ControllerBus(Protocol):
    """What a :class:`Controller` asks of the bus it is attached to (``VirtualBus`` implements it):
    its clock, name and bit rates, the transmission on the wire, and three notices. A controller
    calls nothing else on its bus."""

    @property
    def clock(self) -> Clock:
        """The clock the bus runs on (the controller schedules recovery and retries on it)."""

    @property
    def name(self) -> str:
        """The bus's name (for messages)."""

    @property
    def bitrate(self) -> int:
        """The bus's nominal bit rate in bit/s."""

    @property
    def data_bitrate(self) -> int | None:
        """The bus's CAN FD data bit rate in bit/s; None on a classic bus."""

    @property
    def on_wire(self) -> Transmission | None:
        """The transmission on the wire now (None when idle)."""

    def audience_changed(self) -> None:
        """Who hears, acknowledges or sends frames, or through which callback, may change now."""

    def settle_rx(self) -> None:
        """Bring every controller's receive counters up to date (before they are read)."""

    def request_arbitration(self) -> None:
        """A frame is waiting: arbitrate as soon as the bus is idle."""


class Controller:
    """One CAN controller attached to a :class:`VirtualBus`."""

    def __init__(self, bus: VirtualBus, name: str, bitrate: int, data_bitrate: int | None,
                 listen_only: bool, auto_retransmit: bool, receive_own: bool, fd: bool,
                 auto_recover: bool, on_frame: FrameCallback | None,
                 on_event: EventCallback | None) -> None:
        #: The bus it is attached to. Typed as the concrete bus for callers (``ctrl.bus.detach(ctrl)``)
        #: and for direct calls in the compiled build; the controller itself uses only
        #: :class:`ControllerBus` (tests/bus/test_bus_parts.py holds it to that).
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
        #: The counters as kept: the bus and its fault injector count into them directly; the
        #: receive counters lag until settled (read :attr:`stats`, which settles them first).
        self.counters = ControllerStats()
        #: A phantom sender (the synthetic load of ``BusFaults.set_load``): it sends, nobody hears it.
        self.synthetic = False
        self._recovery: TimerHandle | None = None
        self._mismatch_timer: TimerHandle | None = None
        #: The bus's arbitration cache: the frame at the head of tx_queue when the bus last
        #: arbitrated, and its arbitration key (computed once per frame, not in every arbitration
        #: the frame waits through).
        self.arb_head: CanFrame | None = None
        self.arb_key = 0

    def __repr__(self) -> str:
        return f"<Controller {self.bus.name}/{self.name} {self.state.value} TEC={self.tec} REC={self.rec}>"

    @property
    def stats(self) -> ControllerStats:
        """Frame and error counters (the bus counts received frames per audience and settles
        them here when they are read; under the clock's lock, as deliveries run)."""
        bus = self.bus
        with bus.clock.lock:
            bus.settle_rx()
        return self.counters

    @stats.setter
    def stats(self, value: ControllerStats) -> None:
        bus = self.bus
        with bus.clock.lock:
            bus.settle_rx()
            self.counters = value

    @property
    def on_frame(self) -> FrameCallback | None:
        """``callback(frame, t)`` for every received frame (unless :attr:`rx_table` is set)."""
        return self._on_frame

    @on_frame.setter
    def on_frame(self, value: FrameCallback | None) -> None:
        self.bus.audience_changed()
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
        self.bus.audience_changed()
        self._rx_table = None if value is None else dict(value)

    @property
    def fd(self) -> bool:
        """CAN FD capable: receives (and may send) FD frames."""
        return self._fd

    @fd.setter
    def fd(self, value: bool) -> None:
        self.bus.audience_changed()
        self._fd = value
        self.check_timing()

    @property
    def connected(self) -> bool:
        """False while unplugged (fault injection): it neither sends nor receives."""
        return self._connected

    @connected.setter
    def connected(self, value: bool) -> None:
        self.bus.audience_changed()
        self._connected = value

    @property
    def listen_only(self) -> bool:
        """Receives without acknowledging or sending (a monitor)."""
        return self._listen_only

    @listen_only.setter
    def listen_only(self, value: bool) -> None:
        self.bus.audience_changed()
        self._listen_only = value

    @property
    def bitrate(self) -> int:
        """The controller's own nominal bit rate (a mismatch with the bus makes it see only errors)."""
        return self._bitrate

    @bitrate.setter
    def bitrate(self, rate: int) -> None:
        """Change the nominal bit rate (LSS activate bit timing); the bus re-checks the match."""
        self._bitrate = rate
        self.check_timing()

    @property
    def data_bitrate(self) -> int | None:
        """The controller's own CAN FD data bit rate (None: the bus's)."""
        return self._data_bitrate

    @data_bitrate.setter
    def data_bitrate(self, rate: int | None) -> None:
        self._data_bitrate = rate
        self.check_timing()

    def check_timing(self) -> None:
        """Compare this controller's bit timing with the bus's (after either changed): a mismatch
        makes it see only errors (:attr:`timing_matches` False)."""
        bus = self.bus
        bus.audience_changed()
        self.timing_matches = self._bitrate == bus.bitrate and not (
            self._fd and bus.data_bitrate is not None and self._data_bitrate is not None
            and self._data_bitrate != bus.data_bitrate)
        if self.timing_matches and self.tx_queue and self.connected:
            bus.request_arbitration()

    @property
    def bus_off(self) -> bool:
        """True while the controller is bus-off (it neither sends nor acknowledges)."""
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
            self.bus.request_arbitration()
        elif self._mismatch_timer is None:
            self._mismatch_timer = self.bus.clock.call_soon(self._mismatch_attempt)

    def flush_tx(self) -> None:
        """Drop every queued frame (a frame on the wire completes for nobody)."""
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

    # -- the bus's side: fault confinement, reception, events (called by the bus and its faults) --
    def update_state(self) -> None:
        """Derive the fault-confinement state from TEC and REC (CAN 2.0 §8; bus-off
        is left only by :meth:`recover`) and report a change."""
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
        self.bus.audience_changed()
        self.state = new
        clock = self.bus.clock
        if new is ErrorState.BUS_OFF:
            self.counters.bus_offs += 1
            for frame in self.tx_queue:
                self.emit(TxAbortedEvent(frame, clock.now(), "bus-off"))
            self.tx_queue.clear()
            self.start_recovery()
        self.emit(StateChangeEvent(old, new, self.tec, self.rec, clock.now()))

    def start_recovery(self) -> None:
        """A bus-off controller with ``auto_recover`` recovers after 128 x 11 recessive bits from
        now (CAN 2.0 §8), unless its recovery is already under way."""
        if self.state is ErrorState.BUS_OFF and self.auto_recover and self._recovery is None:
            bus = self.bus
            self._recovery = bus.clock.call_later(BUS_OFF_RECOVERY_BITS / bus.bitrate, self.recover)

    def cancel_recovery(self) -> None:
        """Stop a recovery under way (the bus is not recessive: it is held dominant)."""
        if self._recovery is not None:
            self._recovery.cancel()
            self._recovery = None

    def recover(self) -> None:
        """Leave bus-off (after 128 x 11 recessive bits when ``auto_recover``; or on request)."""
        self.cancel_recovery()
        if self.state is ErrorState.BUS_OFF:
            self.tec = self.rec = 0
            self._set_state(ErrorState.ERROR_ACTIVE)

    def emit(self, event: BusEvent) -> None:
        """Report ``event`` to :attr:`on_event` (if set)."""
        if self.on_event is not None:
            self.on_event(event)

    def count_received(self) -> None:
        """A frame received without error counts REC down (CAN 2.0 §8 rule 8: from above 127 to
        a value between 119 and 127; 120 here). The bus calls it for receivers with REC > 0."""
        self.rec = self.rec - 1 if self.rec <= 127 else 120
        if self.state is not _ACTIVE:
            self.update_state()

    def count_error(self, kind: ErrorKind, transmitter: bool, frame: CanFrame | None, t: float) -> None:
        """An error frame this controller took part in at ``t``, as transmitter or receiver: its
        counters (CAN 2.0 §8 rules 1 and 3; a listen-only controller counts none), the event, the state."""
        self.counters.error_frames += 1
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
                    self.bus.audience_changed()
        self.emit(ErrorFrameEvent(kind, t, transmitter, frame))
        self.update_state()

    def _mismatch_attempt(self) -> None:
        """A controller at the wrong bit rate can never send: every attempt is a bit error."""
        self._mismatch_timer = None
        if not self.tx_queue or not self.connected or self.state is ErrorState.BUS_OFF:
            return
        frame = self.tx_queue[0]
        self.count_error(ErrorKind.BIT, True, frame, self.bus.clock.now())
        if not self.auto_retransmit and self.tx_queue:
            self.tx_queue.popleft()
            self.emit(TxAbortedEvent(frame, self.bus.clock.now(), "single-shot"))
        if self.tx_queue and not self.bus_off:
            self._mismatch_timer = self.bus.clock.call_later(
                ERROR_FRAME_BITS / self.bitrate, self._mismatch_attempt)

