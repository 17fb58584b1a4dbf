"""Fault injection on a virtual bus (docs/bus.md "Faults"): frames dropped or corrupted, noise,
a bus held dominant, synthetic load, controllers unplugged or forced error-passive or bus-off.

:class:`BusFaults` is the injector of one bus (``VirtualBus.faults``; the bus's methods of the same
names call it). What the arbitration engine must consult per frame is the :class:`FaultPlan` it
leaves in ``VirtualBus.fault_plan`` while faults are planned: when there is none, the hot path pays
one ``is None`` test. What the injector needs of its bus is :class:`FaultedBus`; it changes a
controller's counters and state through the controller's public methods.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from gatewaylab.bus.controller import Controller, ErrorFrameEvent, ErrorKind, ErrorState
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.stats import BusStats
from gatewaylab.bus.timing import frame_duration
from gatewaylab.bus.transmission import Outcome, Step, Transmission
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import ConfigError, LocalError

__all__ = ["BusFaults", "FaultPlan", "FaultedBus", "Jam", "Load"]

_BUS_OFF = ErrorState.BUS_OFF
_DROPPED = Outcome.DROPPED
_CRC_ERROR = Outcome.CRC_ERROR


class FaultedBus(Protocol):
    """What :class:`BusFaults` asks of its bus (``VirtualBus`` implements it): clock, bit rate,
    controllers and counters, attaching the phantom load sender, the fault plan the arbitration
    consults, and holding the wire. The injector calls nothing else on its bus."""

    fault_plan: FaultPlan | None
    controllers: list[Controller]
    stats: BusStats

    @property
    def clock(self) -> Clock:
        """The clock the bus runs on."""

    @property
    def bitrate(self) -> int:
        """The bus's nominal bit rate in bit/s."""

    @property
    def on_wire(self) -> Transmission | None:
        """The transmission on the wire now (None when idle)."""

    def attach(self, name: str = "", *, auto_recover: bool = True) -> Controller:
        """Attach a controller (the phantom sender of synthetic load)."""

    def detach(self, ctrl: Controller) -> None:
        """Remove a controller."""

    def audience_changed(self) -> None:
        """Who hears, acknowledges or sends frames may change now."""

    def request_arbitration(self) -> None:
        """A frame is waiting: arbitrate as soon as the bus is idle."""

    def hold(self, now: float) -> None:
        """Occupy the bus from ``now``: nothing arbitrates until :meth:`release`."""

    def release(self, now: float) -> None:
        """The bus is idle again from ``now``."""


class FaultPlan:
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
        """Ask for ``n`` more frames (of ``can_id``, or any frame) in ``rules`` (:attr:`drop` or :attr:`corrupt`)."""
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

    def commit(self, step: Step) -> bool:
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


class Jam:
    """A bus held dominant: until when, who counts as transmitter, the steps of rule 6."""

    __slots__ = ("bus_off", "release", "start", "step", "transmitters", "until")

    def __init__(self, start: float, until: float) -> None:
        self.start = start
        self.until = until
        self.transmitters: list[Controller] = []
        self.bus_off: list[Controller] = []
        self.release = TimerHandle(until, 0, lambda: None, ())
        self.step = TimerHandle(start, 0, lambda: None, ())


@dataclass(slots=True)
class Load:
    """Synthetic bus load: the phantom controller sending ``frame`` for ``percent`` of the time."""

    percent: float
    frame: CanFrame
    timer: TimerHandle | None = None
    controller: Controller | None = field(default=None)



class BusFaults:
    """The fault injector of one bus: what breaks, and how the bus's controllers count it
    (CAN 2.0 §8 'Fault Confinement'). Every method runs on the bus's clock like the bus itself."""

    __slots__ = ("_jam", "_load", "bus")

    def __init__(self, bus: FaultedBus) -> None:
        self.bus = bus
        #: A bus held dominant (stuck_dominant), until it is released.
        self._jam: Jam | None = None
        self._load: Load | None = None

    def _plan(self) -> FaultPlan:
        bus = self.bus
        plan = bus.fault_plan
        if plan is None:
            plan = bus.fault_plan = FaultPlan()
        return plan

    # -- controllers ---------------------------------------------------------------------------
    def disconnect(self, ctrl: Controller) -> None:
        """Unplug a controller: it neither sends nor receives; its queue waits for reconnect."""
        ctrl.connected = False

    def reconnect(self, ctrl: Controller) -> None:
        """Plug a controller back in; the frames it queued meanwhile go out."""
        ctrl.connected = True
        if ctrl.tx_queue:
            self.bus.request_arbitration()

    def force_bus_off(self, ctrl: Controller) -> None:
        """Put a controller bus-off (TEC above 255, CAN 2.0 §8 rule 9); it recovers as configured."""
        ctrl.tec = 256
        ctrl.update_state()

    def force_error_passive(self, ctrl: Controller) -> None:
        """Put a controller's TEC at 128 (error-passive, CAN 2.0 §8 rule 9); every successful
        transmission then counts it down by one, so it is error-active again after its next one
        (rule 7), as a node that just had a burst of errors."""
        if ctrl.state is _BUS_OFF:
            raise LocalError(f"{ctrl.name}: controller is bus-off")
        ctrl.tec = max(ctrl.tec, 128)
        ctrl.update_state()

    # -- frames ----------------------------------------------------------------------------------
    def drop_next(self, n: int = 1, can_id: int | None = None) -> None:
        """The next ``n`` frames (of ``can_id`` only, if given) vanish: the sender sees success,
        nobody receives them."""
        plan = self._plan()
        plan.add(plan.drop, n, can_id)

    def corrupt_next(self, n: int = 1, can_id: int | None = None) -> None:
        """The next ``n`` frames (of ``can_id`` only, if given) arrive corrupted: CRC error
        frame, counters, retransmission (a retransmission is a frame of its own)."""
        plan = self._plan()
        plan.add(plan.corrupt, n, can_id)

    def error_frames(self, duration: float, every: int = 1) -> None:
        """Noise for ``duration`` seconds: one frame in ``every`` that starts in that span ends
        in an error frame (a CRC error to its receivers: transmitter TEC + 8, receivers REC + 1,
        retransmission), as electromagnetic disturbance does (CAN 2.0 §8 rules 1 and 3)."""
        if duration <= 0 or every < 1:
            raise LocalError("error_frames: duration must be > 0 and every >= 1")
        plan = self._plan()
        plan.errors_until = max(plan.errors_until, self.bus.clock.now() + duration)
        plan.errors_every = every
        plan.errors_seen = 0

    # -- a bus held dominant -----------------------------------------------------------------------
    def stuck_dominant(self, duration: float) -> None:
        """Hold the bus dominant for ``duration`` seconds (a jammed transceiver, CANH shorted to
        supply): no frame completes. The frame on the wire is destroyed; every controller that
        has a frame to send is a transmitter and every other one a receiver, and after the first
        error (TEC + 8, REC + 1) each counts + 8 per 8 more dominant bits (CAN 2.0 §8 rule 6),
        so transmitters go bus-off and receivers error-passive. Released, the bus is idle again:
        bus-off controllers recover after 128 x 11 recessive bits, queued frames go out."""
        if duration <= 0:
            raise LocalError("stuck_dominant: duration must be > 0")
        bus = self.bus
        clock = bus.clock
        now = clock.now()
        jam = self._jam
        if jam is not None:
            jam.until = max(jam.until, now + duration)
            jam.release.cancel()
            jam.release = clock.call_at(jam.until, self._release_jam)
            return
        tx = bus.on_wire
        jam = self._jam = Jam(now, now + duration)
        if tx is not None:
            jam.transmitters.append(tx.sender)
            bus.stats.busy_time += now - max(tx.start, bus.stats.since)
        bus.hold(now)         # the bus is busy: nothing arbitrates until the release
        jam.release = clock.call_at(jam.until, self._release_jam)
        # the first error: a bit error for the transmitter, a stuff error after 6 dominant bits
        jam.step = clock.call_later(6 / bus.bitrate, self._jam_step, True)

    @property
    def stuck(self) -> bool:
        """True while the bus is held dominant (:meth:`stuck_dominant`)."""
        return self._jam is not None

    def _jam_step(self, first: bool) -> None:
        """One step of CAN 2.0 §8 rule 6 on a bus held dominant: + 8 per 8 dominant bits."""
        jam = self._jam
        if jam is None:
            return
        bus = self.bus
        now = bus.clock.now()
        counting = False
        bus.stats.error_frames += 1
        for c in list(bus.controllers):
            if not c.connected or c.state is _BUS_OFF or c.synthetic:
                continue
            if c.listen_only:     # sees the error, never counts it (docs/bus.md)
                if first:
                    c.counters.error_frames += 1
                    c.emit(ErrorFrameEvent(ErrorKind.STUFF, now, False, None))
                continue
            if c.tx_queue or c in jam.transmitters:
                if c not in jam.transmitters:
                    jam.transmitters.append(c)
                c.tec += 8
                c.counters.error_frames += 1
                c.emit(ErrorFrameEvent(ErrorKind.BIT, now, True, c.tx_queue[0] if c.tx_queue else None))
                c.update_state()
                if c.state is _BUS_OFF:
                    c.cancel_recovery()   # recovery needs recessive bits: after the release
                    jam.bus_off.append(c)
                else:
                    counting = True
            elif c.rec <= 127:
                c.rec = min(255, c.rec + (1 if first else 8))
                c.counters.error_frames += 1
                c.emit(ErrorFrameEvent(ErrorKind.STUFF, now, False, None))
                if c.rec == 1 and c.timing_matches:
                    bus.audience_changed()
                c.update_state()
                counting = counting or c.rec <= 127
        # after the first error flag (6 bits) the 14th dominant bit, then every 8 bits; once every
        # counter has settled only a node that queues a frame later can change: look each ms
        delay = (14 if first else 8) / bus.bitrate if counting else 0.001
        jam.step = bus.clock.call_later(delay, self._jam_step, False)

    def _release_jam(self) -> None:
        jam = self._jam
        if jam is None:
            return
        self._jam = None
        jam.step.cancel()
        bus = self.bus
        now = bus.clock.now()
        bus.stats.busy_time += now - max(jam.start, bus.stats.since)
        bus.release(now)
        for c in jam.bus_off:
            c.start_recovery()
        for c in bus.controllers:
            if c.tx_queue and c.connected:
                bus.request_arbitration()
                break

    # -- synthetic load ----------------------------------------------------------------------------
    def set_load(self, percent: float, can_id: int = 0x7FF, length: int = 8) -> None:
        """Add synthetic bus load from a phantom node sending ``can_id`` (0 disables)."""
        bus = self.bus
        if self._load is not None:
            if self._load.timer is not None:
                self._load.timer.cancel()
            if self._load.controller is not None:
                bus.detach(self._load.controller)
            self._load = None
        if percent <= 0:
            return
        if percent >= 100:
            raise ConfigError("synthetic load must be below 100 %")
        frame = CanFrame(can_id, bytes(length))
        load = Load(percent, frame)
        ctrl = bus.attach("<load>", auto_recover=True)
        ctrl.synthetic = True
        bus.audience_changed()
        load.controller = ctrl
        self._load = load
        self._load_tick()

    def _load_tick(self) -> None:
        load = self._load
        if load is None or load.controller is None:
            return
        if not load.controller.tx_queue:
            load.controller.send(load.frame)
        bus = self.bus
        period = frame_duration(load.frame, bus.bitrate) * 100.0 / load.percent
        load.timer = bus.clock.call_later(period, self._load_tick)
