"""python-can over the EtherCAT gateways: one master, one bus per channel.

:class:`EthercatHost` owns one :class:`~gatewaylab.hosts.ethercat.backend.MasterBackend` (SOEM on a NIC
or the in-process master on a rig) and the gateways of its segment. Each gateway CAN channel is
handed out as a :class:`GatewayBus` (a ``can.BusABC``), several at once.

The cycle: every ``cycle_us`` the host writes each gateway's outputs, makes one
``backend.exchange()`` and reads the inputs back (:meth:`EthercatHost.cycle`). On a real-time
clock a thread runs it; on a :class:`~gatewaylab.common.clock.SimulatedClock` the clock runs it (a
periodic timer), and ``send()`` runs the simulation until the frame is on the bus and the answers
to it came back up through the gateway, as ``gatewaylab/bus/transport/inprocess.py`` does, so a
canopen SDO client gets its answers without anyone advancing the clock.

Each gateway's side of the cycle is a channel (:mod:`gatewaylab.hosts.canhost.channels`).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

import can
from can.bus import BusState, CanProtocol

from gatewaylab.bus.errorframe import CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_CRTL_RX_OVERFLOW
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, PeriodicTimer, SimulatedClock
from gatewaylab.common.errors import GatewaylabError, LocalError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.canhost.channels import Channel, EcanChannel, EsdChannel
from gatewaylab.hosts.ecanlite.adapter import AdapterConfig, EcanAdapter, SlaveConfig
from gatewaylab.hosts.ecanlite.port import McanPort, PortConfig
from gatewaylab.hosts.esd_can_ethercat import RxOverflowError
from gatewaylab.hosts.ethercat.backend import MasterBackend

__all__ = [
    "MAX_SEND_CYCLES",
    "SETTLE_CYCLES",
    "SHUTDOWN_TIMEOUT",
    "STATE_CHECK_PERIOD",
    "TIMESTAMP_PROFILE",
    "WKC_RECOVER",
    "EthercatHost",
    "GatewayBus",
]


log = logging.getLogger("can.gatewaylab.ethercat")

#: Seconds a shutdown waits for frames already handed to a gateway to reach the bus.
SHUTDOWN_TIMEOUT = 2.0
#: Quiet cycles after which ``send()`` on a simulated clock stops running the simulation.
SETTLE_CYCLES = 4
#: Cycles ``send()`` on a simulated clock runs at most for one frame (a lone node never completes).
MAX_SEND_CYCLES = 2000
#: Consecutive cycles with a wrong working counter after which the host looks at the slaves'
#: states at once and brings those fallen to SAFEOP (SM watchdog after a stalled master) back to OP.
WKC_RECOVER = 10
#: Seconds between two looks at the slaves' AL states anyway: a slave in SAFEOP may still count
#: the datagrams (the working counter stays right) while it takes no outputs.
STATE_CHECK_PERIOD = 0.1
#: The ECAN-Lite encapsulation profile the host selects (0x8010/0x8011:05): compact inline,
#: variable DLC, delta16 timestamps of the bus receive instant in the TxPDO (manual 8.4, 9).
TIMESTAMP_PROFILE = 1


class EthercatHost:
    """One master and the gateway channels on its segment; ``bus(name)`` gives a ``can.BusABC``."""

    def __init__(self, backend: MasterBackend, *, cycle_us: int = 1000, owned: Callable[[], None] | None = None,
                 wall_epoch: float = 0.0) -> None:
        if cycle_us < 100:
            raise LocalError(f"cycle_us {cycle_us} is below 100 us")
        self.backend = backend
        self.clock: Clock = backend.clock
        self.cycle_s = cycle_us / 1e6
        self.simulated = isinstance(self.clock, SimulatedClock)
        #: added to clock times for Message.timestamp (a simulated clock starts at 0)
        self.wall_epoch = wall_epoch
        self.channels: dict[str, Channel] = {}
        #: the ECAN-Lite adapter and MCAN Port, made at start() when there are ECAN-Lite channels
        self.adapter: EcanAdapter | None = None
        self.port: McanPort | None = None
        self.parse_errors = 0
        #: ECAN-Lite overflow_sat + TxPDO images lost, as last reported by an error frame
        self.device_overflow = 0
        self.buses: list[GatewayBus] = []
        self.cycles = 0
        self.wkc_errors = 0
        #: slaves brought back from SAFEOP to OP
        self.recoveries = 0
        self._bad_cycles = 0
        self._state_checked_at = self.clock.now()
        self._owned = owned
        self._timer: PeriodicTimer | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._driver = 0
        self._closed = False
        self._lock = threading.RLock()
        #: notified after every cycle (a send() waiting for room in a Tx path looks again)
        self._cycled = threading.Condition(self._lock)
        if self.simulated:
            self.clock.ensure_lock()

    # -- set-up --------------------------------------------------------------------------------
    def add_esd(self, position: int, bitrate: int = 500_000, name: str = "") -> EsdChannel:
        """An esd CAN-EtherCAT at ``position``; configured when the host starts."""
        ch = EsdChannel(self, position, bitrate, name or f"esd{position}")
        self._add(ch)
        return ch

    def add_ecanlite(self, position: int, can_channel: int = 0, bitrate: int = 1_000_000,
                     data_bitrate: int | None = None, fd: bool = False, pdo_n: int = 3,
                     name: str = "") -> EcanChannel:
        """MCAN channel ``can_channel`` of the ECAN-Lite at ``position``; configured when the host starts.
        Channels of one slave share its PDO multiplier ``pdo_n``."""
        for other in self.channels.values():
            if isinstance(other, EcanChannel) and other.position == position:
                if other.can_channel == can_channel:
                    raise LocalError(f"ECAN-Lite {position} channel {can_channel} twice")
                if other.pdo_n != pdo_n:
                    raise LocalError(f"ECAN-Lite {position}: one pdo_n per slave ({other.pdo_n} and {pdo_n})")
        ch = EcanChannel(self, position, can_channel, bitrate, data_bitrate, fd, pdo_n,
                         name or f"ecan{position}.{can_channel}")
        self._add(ch)
        return ch

    def _ecan(self) -> list[EcanChannel]:
        return [c for c in self.channels.values() if isinstance(c, EcanChannel)]

    def _esd(self) -> list[EsdChannel]:
        return [c for c in self.channels.values() if isinstance(c, EsdChannel)]

    def _start_ecan(self, timeout: float) -> None:
        """One adapter over every ECAN-Lite slave with a channel here, one MCAN Port over it;
        ``adapter.start()`` maps the segment and brings it to SAFEOP, its slaves to OP."""
        ecan = self._ecan()
        positions = sorted({c.position for c in ecan})
        slaves = tuple(SlaveConfig(p, next(c.pdo_n for c in ecan if c.position == p)) for p in positions)
        adapter = EcanAdapter(self.backend, AdapterConfig(slaves, cycle_us=round(self.cycle_s * 1e6)))
        # profile 1: the TxPDO carries delta16 receive timestamps (8.4, 9); the RxPDO sends TSF_NONE
        configs = {k: PortConfig(channels={c.can_channel: c.config for c in ecan if c.position == p},
                                 profile=TIMESTAMP_PROFILE)
                   for k, p in enumerate(positions)}
        port = McanPort(adapter, configs)
        for c in ecan:
            c.slave_k = positions.index(c.position)
        adapter.start(op_timeout=timeout)
        self.adapter, self.port = adapter, port

    def _add(self, ch: Channel) -> None:
        if self._running:
            raise LocalError("add channels before start()")
        if ch.name in self.channels:
            raise LocalError(f"channel {ch.name!r} twice")
        self.channels[ch.name] = ch

    def start(self, timeout: float = 5.0) -> None:
        """Configure every gateway in PREOP, map, SAFEOP, OP, and start cycling."""
        esd = self._esd()
        for ch in esd:
            ch.configure()
        if self._ecan():
            self._start_ecan(timeout)
        else:
            self.backend.config_map()
        # config_map maps the whole segment and the working counter counts every slave: the
        # slaves without a channel here run too, with their default mapping and zero outputs
        used = {ch.position for ch in self.channels.values()}
        others = {s.position for s in self.backend.slaves()} - used
        positions = sorted({ch.position for ch in esd} | others)
        for state in (AlState.SAFEOP, AlState.OP):
            for pos in positions:
                self.backend.request_state(state, pos, timeout)
        for ch in esd:
            ch.attach()
        self._running = True
        #: the thread that started the host drives a simulated clock in recv() (a notifier thread does not)
        self._driver = threading.get_ident()
        if self.simulated:
            self._timer = self.clock.call_every(self.cycle_s, self.cycle)
        else:
            self._thread = threading.Thread(target=self._loop, name="ethercat-host", daemon=True)
            self._thread.start()

    def _loop(self) -> None:
        next_t = self.clock.now()
        while self._running:
            try:
                self.cycle()
            except Exception:   # the loop must go on; the error shows in wkc_errors / logs
                log.exception("EtherCAT cycle failed")
            next_t += self.cycle_s
            delay = next_t - self.clock.now()
            if delay < 0:
                next_t = self.clock.now()
                delay = 0.0
            self.clock.wait(delay)

    def cycle(self) -> None:
        """One process-data cycle for every channel, then received frames to their buses."""
        with self._lock:
            chans = list(self.channels.values())
            for ch in chans:
                ch.before_exchange()
            port = self.port
            if port is not None:
                status = port.cycle_end()         # publish the RxPDOs, exchange
                wkc, expected = status.wkc, status.expected
                port.cycle_begin()                # parse the TxPDOs just exchanged
                self._dispatch_ecan(port)
            else:
                wkc, expected = self.backend.exchange()
            self.cycles += 1
            if wkc != expected:
                self.wkc_errors += 1
                self._bad_cycles += 1
            else:
                self._bad_cycles = 0
            for ch in chans:
                ch.after_exchange(wkc, expected)
            now = self.clock.now()
            if self._bad_cycles >= WKC_RECOVER or now - self._state_checked_at >= STATE_CHECK_PERIOD:
                self._bad_cycles = 0
                self._state_checked_at = now
                self._recover()
            for ch in chans:
                msgs = ch.take()
                if msgs:
                    for bus in self.buses:
                        if bus.channel_name == ch.name:
                            bus.deliver(msgs)
            self._cycled.notify_all()

    def _recover(self) -> None:
        """Bring slaves that fell to SAFEOP back to OP (their gateways keep their state there: the
        esd counters, the ECAN-Lite profile); a slave in INIT/PREOP lost its configuration and is
        only logged (open the bus again)."""
        for s in self.backend.slaves():
            try:
                state, code = self.backend.state(s.position)
                if state == AlState.SAFEOP:
                    log.warning("slave %d fell to SAFEOP (AL status code 0x%04X): back to OP", s.position, code)
                    self.backend.request_state(AlState.OP, s.position, 1.0)
                    self.recoveries += 1
                elif state != AlState.OP:
                    log.error("slave %d is in %s (AL status code 0x%04X): open the bus again",
                              s.position, state.name, code)
            except (GatewaylabError, TimeoutError) as exc:
                log.warning("slave %d: state not read: %s", s.position, exc)

    def _dispatch_ecan(self, port: McanPort) -> None:
        by_key = {(c.slave_k, c.can_channel): c for c in self._ecan()}
        for rx in port.receive():
            ch = by_key.get((rx.slave, rx.channel))
            if ch is not None:
                t = rx.received if rx.received is not None else rx.time
                ch.deliver(rx.frame.to_message(self.timestamp(t), ch.name))
        if port.parse_errors != self.parse_errors:
            self.parse_errors = port.parse_errors
            log.warning("ECAN-Lite TxPDO rejected: %s", port.last_parse_error)
            for c in by_key.values():
                c.deliver(self.error_frame(c.name))
        lost = port.device_overflow + port.lost_images
        if lost != self.device_overflow:
            # frames the device dropped (overflow_sat) or TxPDO images that never reached the host
            # (a process data frame lost or late: its frames were consumed by the device)
            self.device_overflow = lost
            for c in by_key.values():
                c.deliver(self.error_frame(c.name, overflow=True))

    def timestamp(self, t: float) -> float:
        """``Message.timestamp`` for clock time ``t`` (a simulated clock starts at 0, users expect Unix time)."""
        return self.wall_epoch + t

    def error_frame(self, channel: str, *, bus_off: bool = False, overflow: bool = False) -> can.Message:
        """An error frame as SocketCAN reports them: CAN_ERR_BUSOFF (0x40), or controller problem
        CAN_ERR_CRTL (0x04) with data[1] = CAN_ERR_CRTL_RX_OVERFLOW (0x01) for an overflow and
        data[1] = 0 (unspecified) for process data the host could not parse."""
        can_id = CAN_ERR_BUSOFF if bus_off else CAN_ERR_CRTL
        data = bytes([0, CAN_ERR_CRTL_RX_OVERFLOW if overflow else 0, 0, 0, 0, 0, 0, 0])
        return can.Message(timestamp=self.timestamp(self.clock.now()), arbitration_id=can_id,
                           is_error_frame=True, data=data, channel=channel, check=False)

    def bus(self, name: str | None = None, **kwargs: Any) -> GatewayBus:
        """A python-can bus on channel ``name`` (the only one when omitted)."""
        if name is None:
            if len(self.channels) != 1:
                raise LocalError(f"name one of {sorted(self.channels)}")
            name = next(iter(self.channels))
        if name not in self.channels:
            raise LocalError(f"no channel {name!r}; this host has {sorted(self.channels)}")
        return GatewayBus(self, name, **kwargs)

    # -- sending -------------------------------------------------------------------------------
    def send(self, name: str, frame: CanFrame, timeout: float | None) -> None:
        """python-can's send: wait up to ``timeout`` seconds (None: as long as it takes, 0: not at
        all) for room in the channel's Tx path, else :class:`can.CanOperationError`. On a simulated
        clock the waiting runs the cycles (simulated seconds), and a frame sent with a timeout other
        than 0 is then run through as before (on the bus, answers back)."""
        ch = self.channels[name]
        if self._closed or not self._running:
            raise can.CanOperationError("the EtherCAT host is not running")
        if ch.bus_off():
            raise can.CanOperationError(f"{name}: the gateway's CAN controller is bus-off")
        if not self.simulated:
            with self._cycled:
                self._wait_room(ch, frame, timeout)
                self._submit(ch, frame)
            return
        assert isinstance(self.clock, SimulatedClock)
        with self.clock.lock:
            self._wait_room(ch, frame, timeout)
            done = self._submit(ch, frame)
            if timeout != 0:
                self._settle(done)

    def _wait_room(self, ch: Channel, frame: CanFrame, timeout: float | None) -> None:
        """Return once ``ch`` takes ``frame``; cycles pass meanwhile (the cycle thread, or the
        simulated clock advanced here). A simulated clock waits at most MAX_SEND_CYCLES cycles
        for timeout=None: nobody else would ever make room."""
        clock = self.clock
        deadline = None if timeout is None else clock.now() + max(0.0, timeout)
        cycles = 0
        while True:
            try:
                if ch.room(frame):
                    return
            except GatewaylabError as exc:
                raise can.CanOperationError(str(exc)) from exc
            if self._closed or not self._running:
                raise can.CanOperationError("the EtherCAT host is not running")
            left = None if deadline is None else deadline - clock.now()
            if (left is not None and left <= 1e-12) or (self.simulated and cycles >= MAX_SEND_CYCLES):
                raise can.CanOperationError(f"{ch.name}: no room in the gateway's Tx path within "
                                            f"{'the wait limit' if timeout is None else f'{timeout:g} s'}")
            if isinstance(clock, SimulatedClock):
                clock.advance(self.cycle_s if left is None else min(self.cycle_s, left))
            else:
                self._cycled.wait(STATE_CHECK_PERIOD if left is None else min(left, STATE_CHECK_PERIOD))
            cycles += 1

    def _submit(self, ch: Channel, frame: CanFrame) -> Callable[[], bool]:
        try:
            return ch.submit(frame)
        except GatewaylabError as exc:
            raise can.CanOperationError(str(exc)) from exc

    def _settle(self, done: Callable[[], bool]) -> None:
        """Run the simulated clock cycle by cycle until the frame is done and the channels stayed
        quiet (nothing received, nothing in flight) for SETTLE_CYCLES cycles."""
        clock = self.clock
        assert isinstance(clock, SimulatedClock)
        quiet = 0
        for _ in range(MAX_SEND_CYCLES):
            before = sum(b.received for b in self.buses)
            clock.advance(self.cycle_s)
            busy = not done() or any(not ch.idle() for ch in self.channels.values())
            if busy or sum(b.received for b in self.buses) != before:
                quiet = 0
            else:
                quiet += 1
                if quiet >= SETTLE_CYCLES:
                    return

    def pass_time(self, bus: GatewayBus, timeout: float) -> bool:
        """recv() on a simulated clock: run the cycles until ``bus`` has a frame or ``timeout`` passed,
        only on the thread that started the host (others wait in wall time, as a notifier thread must
        not run the simulation on its own)."""
        clock = self.clock
        if not isinstance(clock, SimulatedClock) or threading.get_ident() != self._driver:
            return False
        with clock.lock:
            end = clock.now() + timeout
            while bus._queue.empty() and self._running and clock.now() < end:
                clock.advance(min(self.cycle_s, end - clock.now()))
        return True

    def run_for(self, seconds: float) -> None:
        """Let ``seconds`` pass: on a simulated clock the cycles run now; on a real one this waits."""
        self.clock.wait(seconds)

    # -- shutdown ------------------------------------------------------------------------------
    def close(self, timeout: float = SHUTDOWN_TIMEOUT) -> None:
        """Let frames in flight reach the bus (at most ``timeout``), stop cycling, every gateway
        to PREOP (its queues flushed, outputs no longer taken), close what the host opened."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._running:
                deadline = self.clock.now() + timeout
                while (any(not ch.idle() for ch in self.channels.values())
                       and self.clock.now() < deadline):
                    self.clock.wait(self.cycle_s)
            self._running = False
            if self._timer is not None:
                self._timer.cancel()
            if self._thread is not None:
                self._thread.join(timeout=5.0)
            with self._cycled:
                self._cycled.notify_all()     # a send() waiting for room gives up
            for bus in list(self.buses):
                bus.wake()
            for ch in self.channels.values():
                try:
                    ch.stop()
                except (GatewaylabError, TimeoutError) as exc:
                    log.warning("%s: could not bring the gateway to PREOP: %s", ch.name, exc)
            try:   # every slave the host brought up, the ECAN-Lites and those without a channel
                self.backend.request_state(AlState.PREOP, None, timeout)
            except (GatewaylabError, TimeoutError) as exc:
                log.warning("could not bring the segment to PREOP: %s", exc)
        finally:
            try:
                self.backend.close()
            finally:
                if self._owned is not None:
                    self._owned()

    def __enter__(self) -> EthercatHost:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_WAKE = can.Message(arbitration_id=0, check=False)


class GatewayBus(can.BusABC):
    """``can.BusABC`` on one gateway channel of an :class:`EthercatHost`.

    ``send()`` hands the frame to the gateway in the next cycle (a simulated clock runs until it is
    on the bus and the answers came back); ``recv()`` returns received frames (Message.timestamp:
    the host's time of reception plus ``wall_epoch``) and error frames (bus-off, Rx overflow)."""

    def __init__(self, host: EthercatHost, channel_name: str, *, can_filters: can.typechecking.CanFilters | None = None,
                 owns_host: bool = False, **kwargs: Any) -> None:
        self.host = host
        self.channel_name = channel_name
        self.channel_info = f"gatewaylab EtherCAT {channel_name}"
        self.received = 0
        self._owns_host = owns_host
        self._queue: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        fd = host.channels[channel_name].fd
        super().__init__(channel=channel_name, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        host.buses.append(self)

    def deliver(self, msgs: list[can.Message]) -> None:
        """The host's cycle hands this channel's received frames to the bus for ``recv()``."""
        self.received += len(msgs)
        for m in msgs:
            self._queue.put(m)

    def wake(self) -> None:
        """Make a ``recv()`` blocked in another thread return None (shutdown, host closed)."""
        self._queue.put(_WAKE)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """python-can's send: the gateway's errors become :class:`can.CanOperationError`."""
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info} was shut down")
        if msg.is_fd and not self.host.channels[self.channel_name].fd:
            raise can.CanOperationError(f"{self.channel_info} is a classic CAN channel (opened with fd=False): "
                                        "CAN FD frames cannot be sent")
        try:
            frame = CanFrame.from_message(msg)
        except GatewaylabError as exc:
            raise can.CanOperationError(str(exc)) from exc
        try:
            self.host.send(self.channel_name, frame, timeout)
        except RxOverflowError as exc:
            raise can.CanOperationError(str(exc)) from exc

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """On a simulated clock, ``recv(timeout)`` on the thread that started the host lets up to
        ``timeout`` of simulated time pass (the cycles run) instead of waiting wall time."""
        if not (self.host.simulated and timeout is not None and timeout > 0):
            return super().recv(timeout)
        clock = self.host.clock
        end = clock.now() + timeout
        while True:
            if self._queue.empty() and not self.host.pass_time(self, end - clock.now()):
                return super().recv(timeout)       # another thread (a notifier): wall time
            msg = super().recv(0)
            if msg is not None or clock.now() >= end or self._is_shutdown:
                return msg

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            if timeout is None:
                msg = self._queue.get()
            elif timeout <= 0:
                msg = self._queue.get_nowait()
            else:
                msg = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None, False
        if msg is _WAKE:
            return None, False
        return msg, False

    @property
    def state(self) -> BusState:
        """ERROR while the gateway's controller is bus-off, else ACTIVE."""
        return BusState.ERROR if self.host.channels[self.channel_name].bus_off() else BusState.ACTIVE

    @state.setter
    def state(self, new_state: BusState) -> None:
        if new_state is not BusState.ACTIVE:
            raise can.CanOperationError("the gateway channels are always active (no listen-only mode)")

    def shutdown(self) -> None:
        """Wake a waiting ``recv()``, leave the host (and close it when this bus owns it)."""
        if self._is_shutdown:
            return
        super().shutdown()
        self.wake()          # a recv() waiting in a notifier thread returns None
        if self in self.host.buses:
            self.host.buses.remove(self)
        if self._owns_host:
            self.host.close()
