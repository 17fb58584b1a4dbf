"""python-can interface ``gatewaylab``: ``can.Bus(interface="gatewaylab", channel=ENDPOINT)``.

Registered in the entry-point group ``can.interface``, so every python-can tool and
``canopen.Network.connect(interface="gatewaylab", channel=...)`` reaches a bus of a running rig
from another process. ENDPOINT is what ``gatewaylab run`` prints: ``unix:/path/to/sock`` or
``tcp:127.0.0.1:PORT``.

What a SocketCAN user expects holds here too (docs/bus-wire.md):

* the transmit queue is bounded (``tx_queue_len`` frames handed to the rig and not yet on the
  bus); when it is full ``send(msg, timeout)`` waits up to ``timeout`` and then raises
  ``can.CanOperationError`` (at once when the controller is error-passive or bus-off: nobody
  acknowledges); nothing is dropped silently;
* ``shutdown()`` waits (at most ``shutdown_timeout``) until the rig has put every accepted frame
  on the bus; frames still queued after that stay queued in the rig, as in a SocketCAN device;
* a ``recv()`` in another thread (a ``can.Notifier``) overtaken by ``shutdown()`` returns None when
  its timeout ends (at once for ``recv(None)``), as python-can's ``virtual`` and ``socketcan`` do;
  any call after ``shutdown()`` raises ``can.CanOperationError``; ``recv(0)`` returns what
  the socket already holds (the poll loop of a cyclic task);
* ``Message.timestamp`` is Unix time (the rig's bus time + the rig clock's ``wall_epoch``),
  ``Message.channel`` the channel given to ``can.Bus``, own echoes have ``is_rx=False``;
* acceptance filters are applied by the rig (filtered frames do not cross the socket);
* ``listen_only=True`` joins as a bus monitor: the rig-side controller never transmits, never
  acknowledges and never takes part in arbitration; ``send()`` raises ``can.CanOperationError``.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import can
from can.bus import BusState, CanProtocol

from gatewaylab.bus import errorframe, wire
from gatewaylab.bus.frame import FD_DLC_TO_LEN, CanFrame
from gatewaylab.common.endpoint import EndpointError, EndpointKind, parse_endpoint
from gatewaylab.common.errors import GatewaylabError

log = logging.getLogger("can.gatewaylab")

_STATE_NAMES = {wire.ControllerStateCode.ERROR_ACTIVE: "error-active",
                wire.ControllerStateCode.ERROR_PASSIVE: "error-passive",
                wire.ControllerStateCode.BUS_OFF: "bus-off"}


def _error_frame(record: wire.Status) -> errorframe.ErrorFrame | None:
    """The SocketCAN error frame of a STATUS record: a bus error, or a state change that a Linux
    CAN driver reports (None for a state record without the old state, from an older rig)."""
    if record.kind is wire.StatusKind.ERROR_FRAME:
        return errorframe.bus_error(record.error.name.lower(), record.transmitter, record.tec, record.rec)
    if record.old is None or record.old == record.state:
        return None
    return errorframe.state_change(_STATE_NAMES[record.old], _STATE_NAMES[record.state], record.tec, record.rec)

#: Frames handed to the rig and not yet on the bus. A SocketCAN device queues 10 by default
#: (txqueuelen); a socket round trip costs more than a driver's, so more are allowed in flight.
DEFAULT_TX_QUEUE_LEN = 128


def _connect(channel: str, timeout: float) -> socket.socket:
    try:
        ep = parse_endpoint(channel, bare_path=EndpointKind.UNIX)
    except EndpointError as exc:
        raise can.CanInitializationError(str(exc)) from None
    if ep.kind is EndpointKind.UNIX:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        try:
            sock.connect(ep.path)
        except OSError:
            sock.close()
            raise
    elif ep.kind is EndpointKind.TCP:
        if not ep.is_local:
            raise can.CanInitializationError(f"gatewaylab endpoints live on this host only, not {ep.host!r}")
        sock = socket.create_connection((ep.host, ep.port), timeout=timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    else:
        raise can.CanInitializationError(f"{channel!r} is not a bus endpoint (unix:PATH or tcp:HOST:PORT)")
    return sock


def _fd_padded(data: bytes) -> bytes:
    """An FD payload padded with zeros to the next valid FD length (12 for 10 bytes), as SocketCAN
    does; longer than 64 bytes stays as it is (and is refused)."""
    n = len(data)
    if n <= 8:
        return data
    for length in FD_DLC_TO_LEN[9:]:
        if n <= length:
            return data + bytes(length - n)
    return data


def _filter_of(entry: Any) -> wire.AcceptanceFilter:
    extended = entry.get("extended")
    match = (wire.FilterMatch.ANY if extended is None
             else wire.FilterMatch.EXTENDED if extended else wire.FilterMatch.STANDARD)
    return wire.AcceptanceFilter(int(entry["can_id"]) & 0x1FFFFFFF, int(entry["can_mask"]) & 0x1FFFFFFF, match)


class GatewaylabBus(can.BusABC):
    """A python-can bus connected to a virtual bus of a running ``gatewaylab run``."""

    def __init__(self, channel: Any, receive_own_messages: bool = False, fd: bool = True,
                 name: str = "", connect_timeout: float = 5.0,
                 can_filters: can.typechecking.CanFilters | None = None,
                 tx_queue_len: int = DEFAULT_TX_QUEUE_LEN, shutdown_timeout: float = 5.0,
                 listen_only: bool = False, **kwargs: Any) -> None:
        endpoint = self._endpoint(channel)
        #: a bus monitor: the rig-side controller never transmits, never acknowledges
        self.listen_only = listen_only
        if tx_queue_len < 1:
            raise can.CanInitializationError(f"tx_queue_len must be at least 1, got {tx_queue_len}")
        self._channel = channel
        self._fd_enabled = fd
        self._tx_queue_len = tx_queue_len
        self._shutdown_timeout = shutdown_timeout
        self._decoder = wire.RecordDecoder()
        #: received messages not yet returned by recv()
        self._rx: deque[can.Message] = deque()
        #: frames sent to the rig whose TXDONE has not come back yet
        self._outstanding = 0
        #: FILTER records sent whose acknowledgement has not come back: until then this side
        #: filters too (frames already on their way were filtered with the old filters)
        self._filters_pending = 0
        self._soft_filters = False
        self._server_filters: tuple[wire.AcceptanceFilter, ...] = ()
        self._epoch = 0.0
        self._welcome: wire.Welcome | None = None
        self._timebase = False
        #: why the connection ended (the rig went away or said BYE); None while it is up
        self._lost: str | None = None
        self._closing = False
        self._closed = False
        self._cond = threading.Condition()
        self._reading = False
        self._send_lock = threading.Lock()
        self.controller_state = wire.ControllerStateCode.ERROR_ACTIVE
        #: frames the rig reported aborted (bus-off) or refused
        self.tx_errors = 0
        try:
            self._sock = _connect(endpoint, connect_timeout)
        except OSError as exc:
            raise can.CanInitializationError(f"cannot connect to gatewaylab bus {endpoint}: {exc}") from exc
        self._wake_r, self._wake_w = socket.socketpair()
        try:
            self._sock.sendall(wire.encode_hello(name or f"python-can-{os.getpid()}", receive_own_messages, fd,
                                                 listen_only))
            welcome = self._handshake(connect_timeout)
        except BaseException:
            self._close_sockets()
            raise
        self.bus_name = welcome.bus_name
        self.bitrate = welcome.bitrate
        self.data_bitrate = welcome.data_bitrate or None
        self._bus_fd = welcome.fd
        self.channel_info = f"gatewaylab {welcome.bus_name} via {endpoint}"
        self._sock.settimeout(None)
        self._sock.setblocking(False)
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD if (welcome.fd and fd) else CanProtocol.CAN_20

    @property
    def wall_epoch(self) -> float:
        """Unix time of the rig's bus time 0 (its TIMEBASE record): ``Message.timestamp - wall_epoch`` is the
        time since the rig started, the time base of its traces and of ``gatewaylab monitor``."""
        return self._epoch

    def _endpoint(self, channel: Any) -> str:
        """The endpoint to connect to for ``channel`` (which Message.channel reports as given)."""
        if not isinstance(channel, str) or not channel:
            raise can.CanInitializationError("channel must be an endpoint like unix:/path or tcp:127.0.0.1:PORT")
        return channel

    # -- connection -----------------------------------------------------------------------------
    def _handshake(self, timeout: float) -> wire.Welcome:
        deadline = time.monotonic() + timeout
        while self._welcome is None or not self._timebase:
            self._sock.settimeout(max(0.001, deadline - time.monotonic()))
            try:
                data = self._sock.recv(65536)
            except TimeoutError:
                raise can.CanInitializationError("gatewaylab server did not answer HELLO in time") from None
            except OSError as exc:
                raise can.CanInitializationError(f"connection to the gatewaylab server lost: {exc}") from exc
            if not data:
                raise can.CanInitializationError("gatewaylab server closed the connection during HELLO")
            try:
                records = self._decoder.feed(data)
            except GatewaylabError as exc:
                raise can.CanInitializationError(f"bad answer from server: {exc}") from exc
            for record in records:
                if isinstance(record, wire.Bye) and self._welcome is None:
                    raise can.CanInitializationError(f"server refused: {record.reason}")
                self._handle(record)
        return self._welcome

    def _close_sockets(self) -> None:
        for s in (self._sock, self._wake_r, self._wake_w):
            try:
                s.close()
            except OSError:
                pass

    def _handle(self, record: wire.Record) -> None:
        """Take one record from the rig (holding ``_cond`` once the bus is up)."""
        if isinstance(record, wire.FrameRecord):
            msg = record.frame.to_message(self._epoch + record.timestamp, self._channel)
            if record.echo:
                msg.is_rx = False
            if self._filters_pending and not self._matches_filters(msg):
                return
            self._rx.append(msg)
        elif isinstance(record, wire.TxDone):
            self._outstanding = max(0, self._outstanding - record.count)
            if record.outcome is not wire.TxOutcome.TRANSMITTED:
                self.tx_errors += record.count
                log.warning("%s: %d frame(s) not transmitted: %s (controller %s)", self.channel_info,
                            record.count, record.outcome.name.lower(), self.controller_state.name)
        elif isinstance(record, wire.Status):
            self.controller_state = record.state
            err = _error_frame(record)
            if err is not None:
                # laid out as SocketCAN's error frames (linux/can/error.h): class bits in the id
                self._rx.append(can.Message(timestamp=self._epoch + record.timestamp, is_error_frame=True,
                                            arbitration_id=err.can_id, is_extended_id=True, dlc=8,
                                            data=err.data, channel=self._channel, check=False))
        elif isinstance(record, wire.Filters):
            self._filters_pending = max(0, self._filters_pending - 1)
        elif isinstance(record, wire.Welcome):
            self._welcome = record
        elif isinstance(record, wire.TimeBase):
            self._epoch = record.wall_epoch
            self._timebase = True
        elif isinstance(record, wire.Bye):
            self._lost = f"rig closed the connection: {record.reason}"
        else:
            self._lost = f"unexpected {type(record).__name__} record from the rig"

    def _read(self, timeout: float | None) -> None:
        """Wait for data from the rig (or a wake-up) and take what came; called without
        ``_cond`` by the one thread that reads at a time."""
        try:
            readable, _, _ = select.select([self._sock, self._wake_r], [], [], timeout)
        except (OSError, ValueError) as exc:
            with self._cond:
                self._lost = self._lost or f"connection to the rig lost: {exc}"
            return
        if self._wake_r in readable:
            try:
                while self._wake_r.recv(4096):
                    pass
            except OSError:
                pass
        if self._sock not in readable:
            return
        try:
            data = self._sock.recv(262144)
        except BlockingIOError:
            return
        except OSError as exc:
            with self._cond:
                self._lost = self._lost or f"connection to the rig lost: {exc}"
            return
        with self._cond:
            if not data:
                self._lost = self._lost or "the rig closed the connection"
                return
            try:
                records = self._decoder.feed(data)
            except GatewaylabError as exc:
                self._lost = f"bad data from the rig: {exc}"
                return
            for record in records:
                self._handle(record)

    def _wait(self, ready: Callable[[], bool], timeout: float | None, interruptible: bool = True) -> bool:
        """Wait until ``ready()`` holds (checked holding ``_cond``), at most ``timeout`` seconds.

        One thread at a time reads the socket and takes every record for everybody (frames for
        recv, TXDONE for send); the others wait on ``_cond`` and look again after each read.
        Stops early when the connection is lost, and, if ``interruptible``, when shutdown()
        began. Returns ``ready()``.

        A timeout that is over before this thread read (``recv(0)``, the poll of a cyclic task)
        still takes what the socket already holds: one read that does not wait."""
        deadline = None if timeout is None else time.monotonic() + timeout
        cond = self._cond
        polled = False
        with cond:
            while True:
                if ready():
                    return True
                if self._lost is not None or (interruptible and self._closing):
                    return False
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    if polled or self._reading:   # read once, or another thread is reading
                        return False
                    remaining = 0.0
                if self._reading:
                    cond.wait(remaining)
                    continue
                polled = True
                self._reading = True
                cond.release()
                try:
                    self._read(remaining)
                finally:
                    cond.acquire()
                    self._reading = False
                    cond.notify_all()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass

    # -- python-can API --------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closing or self._closed:
            raise can.CanOperationError(f"{self.channel_info} was shut down")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Hand a message to the rig's bus (python-can ``BusABC.send``)."""
        self._check_open()
        if self.listen_only:
            raise can.CanOperationError("this bus was opened with listen_only=True: it never transmits")
        if msg.is_fd:
            if not self._fd_enabled:
                raise can.CanOperationError("this bus was opened with fd=False: CAN FD frames cannot be sent")
            if not self._bus_fd:
                raise can.CanOperationError(f"bus {self.bus_name} is classic CAN: CAN FD frames cannot be sent")
            data = bytes(msg.data) if msg.data is not None else b""
            padded = _fd_padded(data)
            if padded is not data and not msg.is_remote_frame:
                msg = can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                                  is_extended_id=msg.is_extended_id, is_fd=True, bitrate_switch=msg.bitrate_switch,
                                  error_state_indicator=msg.error_state_indicator, data=padded,
                                  channel=msg.channel, check=False)
        try:
            frame = CanFrame.from_message(msg)
        except GatewaylabError as exc:
            raise can.CanOperationError(str(exc)) from exc
        record = wire.encode_frame(frame)
        with self._send_lock:
            self._wait(self._room_or_hopeless, timeout)
            if not self._room():
                self._check_open()
                if self._lost is not None:
                    raise can.CanOperationError(self._lost)
                raise can.CanOperationError(self._queue_full_reason(timeout))
            with self._cond:
                self._outstanding += 1
            self._write(record, timeout)

    def _room(self) -> bool:
        return self._outstanding < self._tx_queue_len

    def _room_or_hopeless(self) -> bool:
        # an error-passive or bus-off controller is not being acknowledged (a lone node): room
        # would come only when another node appears, so a full queue raises at once
        return (self._outstanding < self._tx_queue_len
                or self.controller_state is not wire.ControllerStateCode.ERROR_ACTIVE)

    def _queue_full_reason(self, timeout: float | None) -> str:
        reason = f"transmit queue full: {self._outstanding} frames handed to the rig are not on the bus"
        if timeout is not None:
            reason += f" after {timeout} s"
        if self.controller_state is not wire.ControllerStateCode.ERROR_ACTIVE:
            reason += (f" (controller {self.controller_state.name.lower()}: is another node acknowledging? "
                       "Add a second client or run the rig with --acker)")
        return reason

    def _write(self, data: bytes, timeout: float | None) -> None:
        view = memoryview(data)
        while view:
            try:
                sent = self._sock.send(view)
            except BlockingIOError:
                _, writable, _ = select.select([], [self._sock], [], timeout)
                if not writable:
                    raise can.CanOperationError("send timed out: the rig does not read") from None
                continue
            except OSError as exc:
                raise can.CanOperationError(f"connection to the rig lost: {exc}") from exc
            view = view[sent:]

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """``BusABC.recv``, ending with None when ``shutdown()`` interrupts it."""
        self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            msg, already_filtered = self._recv_internal(remaining)
            if msg is None:
                return None
            if already_filtered or self._matches_filters(msg):
                return msg
            if deadline is not None and time.monotonic() >= deadline:
                return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        if not self._wait(self._has_rx, timeout):
            if self._lost is not None and not self._closing and not self._rx:
                raise can.CanOperationError(self._lost)
            if self._closing and deadline is not None:
                self._linger(deadline)
            return None, False
        with self._cond:
            return self._rx.popleft(), not self._soft_filters

    def _linger(self, deadline: float) -> None:
        """A recv() that shutdown() overtook returns None when its own timeout ends, as a recv() of
        python-can's ``virtual`` and ``socketcan`` buses does: a ``can.Notifier`` whose bus is shut down
        before ``notifier.stop()`` then finds itself stopped instead of calling recv() again on a closed
        bus (which raises). The socket is not touched meanwhile."""
        with self._cond:
            while (left := deadline - time.monotonic()) > 0:
                self._cond.wait(left)

    def _has_rx(self) -> bool:
        return bool(self._rx)

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        entries = tuple(_filter_of(f) for f in filters or ())
        soft = len(entries) > wire.MAX_FILTERS
        server_side = () if soft else entries
        with self._cond:
            self._soft_filters = soft
            if server_side == self._server_filters:
                return
            self._server_filters = server_side
            self._filters_pending += 1
        with self._send_lock:
            self._write(wire.encode_filters(server_side), None)

    def flush_tx_buffer(self) -> None:
        """Not possible: frames handed to the rig cannot be called back."""
        raise NotImplementedError("frames handed to the rig are on their way to the bus")

    @property
    def state(self) -> BusState:
        """python-can's view of the remote controller: ERROR when bus-off, PASSIVE when listen-only."""
        if self.controller_state is wire.ControllerStateCode.BUS_OFF:
            return BusState.ERROR
        return BusState.PASSIVE if self.listen_only else BusState.ACTIVE

    @state.setter
    def state(self, new_state: BusState) -> None:
        # listen-only is chosen when connecting (listen_only=True), as the rig-side controller is made then
        wanted = BusState.PASSIVE if self.listen_only else BusState.ACTIVE
        if new_state is not wanted:
            raise can.CanOperationError(f"this gatewaylab connection is {wanted.name.lower()}: open it with "
                                        f"listen_only={new_state is BusState.PASSIVE} instead")

    def shutdown(self) -> None:
        """Stop periodic tasks, wake a recv() in another thread (it returns None), wait at most
        ``shutdown_timeout`` until the rig has put every accepted frame on the bus, close."""
        if self._closing or self._closed:
            super().shutdown()
            return
        self.stop_all_periodic_tasks()
        with self._cond:
            self._closing = True
            self._cond.notify_all()   # threads waiting in recv()/send() without reading look again
        self._wake()                  # and the one reading leaves its select()
        drained = self._wait(self._drained, self._shutdown_timeout, interruptible=False)
        if not drained and self._lost is None:
            log.info("%s: shutdown leaves %d frame(s) queued in the rig (controller %s)", self.channel_info,
                     self._outstanding, self.controller_state.name.lower())
        with self._send_lock:
            try:
                self._sock.setblocking(True)
                self._sock.settimeout(1.0)
                self._sock.sendall(wire.encode_bye("client shutdown"))
            except OSError:
                pass
        with self._cond:
            self._closed = True
            # a reader may still be in select(): wake it before the sockets go
            self._wake()
            for _ in range(50):
                if not self._reading:
                    break
                self._cond.wait(0.1)
            self._close_sockets()
        super().shutdown()

    def _drained(self) -> bool:
        # a controller that is not error-active is not being acknowledged: waiting would not help,
        # the rig keeps the frames queued
        return self._outstanding == 0 or self.controller_state is not wire.ControllerStateCode.ERROR_ACTIVE
