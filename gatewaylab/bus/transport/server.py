"""Cross-process endpoint of a virtual bus: a Unix-socket or 127.0.0.1 TCP server.

Each connected client becomes one controller on the bus. Runs inside the rig runtime's loop
(callbacks hold ``clock.lock``); the record format is :mod:`gatewaylab.bus.wire`.
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from gatewaylab.bus import controller as events
from gatewaylab.bus import wire
from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import BusEvent, Controller
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.transport.outbox import Outbox, accept_client, receive
from gatewaylab.bus.transport.unix_file import Identity, bind_unix, remove_unix
from gatewaylab.common.clock import TimerHandle
from gatewaylab.common.errors import ConfigError, GatewaylabError, LocalError, ProtocolError

__all__ = ["CONTROL_BACKLOG", "MAX_BACKLOG", "ORPHAN_PATIENCE", "BusServer", "Reactor"]


log = logging.getLogger(__name__)

#: Unsent bytes a client may let pile up before the frames it receives are dropped (and counted) until
#: it reads again, as a full SocketCAN receive queue drops frames for a socket that does not read; the
#: client stays connected and its own sends keep being acknowledged (BusServer.max_backlog).
MAX_BACKLOG = 8 * 1024 * 1024
#: Room above that for the records a client cannot go without (TXDONE, STATUS, WELCOME); a client whose
#: backlog passes it even so is disconnected.
CONTROL_BACKLOG = 1024 * 1024
#: A departed client's queued frames stay on the bus until sent; if none of them completes for
#: this long (bus time: nobody acknowledges), the rest are given up with a warning.
ORPHAN_PATIENCE = 2.0

#: The bus's error kinds as the STATUS record's tail carries them (docs/bus-wire.md).
_ERROR_CODES = {kind: wire.ErrorCode[kind.name] for kind in events.ErrorKind}
_STATE_CODES = {
    events.ErrorState.ERROR_ACTIVE: wire.ControllerStateCode.ERROR_ACTIVE,
    events.ErrorState.ERROR_PASSIVE: wire.ControllerStateCode.ERROR_PASSIVE,
    events.ErrorState.BUS_OFF: wire.ControllerStateCode.BUS_OFF,
}


class Reactor(Protocol):
    """What the server needs from the loop that runs it (the rig runtime)."""

    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` when ``fd`` is readable."""

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` for readability."""

    def add_writer(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` when ``fd`` is writable."""

    def remove_writer(self, fd: int) -> None:
        """Stop watching ``fd`` for writability."""


class _Client:
    def __init__(self, server: BusServer, sock: socket.socket, peer: str) -> None:
        self.server = server
        self.sock = sock
        self.peer = peer
        self.decoder = wire.RecordDecoder()
        self.controller: Controller | None = None
        self.outbox = Outbox(sock, server.reactor, server.max_backlog + CONTROL_BACKLOG, self._broken,
                             self._overflow)
        #: received frames dropped because the client did not read (all of them; the current run)
        self.rx_dropped = 0
        self._dropping = 0
        self.closed = False
        #: writing to the client failed; its data is still read until the end
        self.broken = False
        #: SocketCAN's loopback of own frames: the echo is made here, when the bus reports the
        #: frame transmitted, so it carries the ECHO flag (python-can's ``is_rx=False``).
        self.receive_own = False
        self.filters: tuple[wire.AcceptanceFilter, ...] = ()
        #: frames of this client that completed (progress of a departed client's queue)
        self.completed = 0

    # bus -> client
    def on_frame(self, frame: CanFrame, t: float) -> None:
        self.write_frame(wire.encode_frame(frame, t))

    def on_frame_filtered(self, frame: CanFrame, t: float) -> None:
        for f in self.filters:
            if f.accepts(frame):
                self.write_frame(wire.encode_frame(frame, t))
                return

    def write_frame(self, data: bytes) -> None:
        """A frame for the client: dropped and counted while its backlog is over ``max_backlog`` (see
        MAX_BACKLOG), one log line when the dropping starts and one when the client reads again."""
        server = self.server
        if len(self.outbox.out) <= server.max_backlog:
            if self._dropping:
                log.info("bus %s: %s reads again (%d received frames dropped)", server.bus.name, self.peer,
                         self._dropping)
                self._dropping = 0
            self.write(data)
            return
        if not self._dropping:
            log.warning("bus %s: %s does not read: the frames it receives are dropped until it reads again",
                        server.bus.name, self.peer)
        self._dropping += 1
        self.rx_dropped += 1
        server.rx_dropped += 1

    def accepts(self, frame: CanFrame) -> bool:
        return not self.filters or any(f.accepts(frame) for f in self.filters)

    def on_event(self, ev: BusEvent) -> None:
        if self.closed:   # departed, its queue still on the bus
            if isinstance(ev, (events.TxDoneEvent, events.TxAbortedEvent)):
                self.completed += 1
            self.server.orphan_progress(self)
            return
        if isinstance(ev, events.TxDoneEvent):
            self.completed += 1
            if self.receive_own and self.accepts(ev.frame):
                self.write_frame(wire.encode_frame(ev.frame, ev.timestamp, echo=True))
            self.write(wire.encode_txdone(wire.TxOutcome.TRANSMITTED))
        elif isinstance(ev, events.TxAbortedEvent):
            self.completed += 1
            self.write(wire.encode_txdone(wire.TxOutcome.ABORTED))
        elif isinstance(ev, events.ErrorFrameEvent):
            ctrl = self.controller
            assert ctrl is not None
            self.write(wire.encode_status(wire.StatusKind.ERROR_FRAME, _STATE_CODES[ctrl.state],
                                          ctrl.tec, ctrl.rec, ev.timestamp, _ERROR_CODES[ev.kind],
                                          ev.transmitter))
        elif isinstance(ev, events.StateChangeEvent):
            self.write(wire.encode_status(wire.StatusKind.STATE, _STATE_CODES[ev.new], ev.tec, ev.rec,
                                          ev.timestamp, old=_STATE_CODES[ev.old]))

    def write(self, data: bytes) -> None:
        if not (self.closed or self.broken):
            self.outbox.write(data)

    def _overflow(self, size: int) -> None:
        self.server.drop(self, f"client does not read: {size} bytes backlog")

    def _broken(self, exc: OSError) -> None:
        """The client stopped reading (closed, or shut its side down): what it sent before is still
        read and put on the bus; it is disconnected at the end of its data."""
        log.info("bus %s: %s stopped reading: %s", self.server.bus.name, self.peer, exc)
        self.broken = True
        self.outbox.close()

    # client -> bus
    def readable(self) -> None:
        data = receive(self.sock)
        if data is None:
            return
        if isinstance(data, OSError):
            self.server.drop(self, f"receive failed: {data}")
            return
        if not data:
            self.server.drop(self, "client closed the connection", notify=False)
            return
        try:
            records = self.decoder.feed(data)
            for record in records:
                self.handle(record)
                if self.closed:
                    return
        except GatewaylabError as exc:
            self.server.drop(self, f"malformed data: {exc}")

    def handle(self, record: wire.Record) -> None:
        if isinstance(record, wire.FrameRecord):
            ctrl = self.controller
            if ctrl is None:
                raise ProtocolError("FRAME before HELLO")
            try:
                ctrl.send(record.frame)
            except LocalError as exc:
                # what the controller refuses (bus-off, an FD frame it cannot send) is one
                # refused frame, reported to the client; the connection stays up
                self.server.refused += 1
                log.info("bus %s: %s: frame refused: %s", self.server.bus.name, self.peer, exc)
                self.write(wire.encode_txdone(wire.TxOutcome.REFUSED))
        elif isinstance(record, wire.Filters):
            if self.controller is None:
                raise ProtocolError("FILTER before HELLO")
            self.filters = record.filters
            self.controller.on_frame = self.on_frame_filtered if record.filters else self.on_frame
            self.write(wire.encode_filters(record.filters))   # in force from here on
        elif isinstance(record, wire.Hello):
            if self.controller is not None:
                raise ProtocolError("second HELLO")
            if record.version != wire.VERSION:
                raise ProtocolError(f"protocol version {record.version} not supported (need {wire.VERSION})")
            bus = self.server.bus
            self.receive_own = record.receive_own
            self.controller = bus.attach(record.name or self.peer, fd=record.fd, on_frame=self.on_frame,
                                         on_event=self.on_event, listen_only=record.listen_only)
            self.write(wire.encode_welcome(bus.name, bus.bitrate, bus.data_bitrate))
            self.write(wire.encode_timebase(bus.clock.wall_epoch))
        elif isinstance(record, wire.Bye):
            self.server.drop(self, f"client said bye: {record.reason}", notify=False)
        else:
            raise ProtocolError(f"{type(record).__name__} is not a client record")


class BusServer:
    """Serves one virtual bus to other processes."""

    def __init__(self, bus: VirtualBus, reactor: Reactor, *, unix_path: Path | None = None,
                 tcp_port: int | None = None) -> None:
        if (unix_path is None) == (tcp_port is None):
            raise ConfigError("give exactly one of unix_path and tcp_port")
        self.bus = bus
        self.reactor = reactor
        self.clients: list[_Client] = []
        self.dropped: list[str] = []
        #: departed clients whose queued frames are still being transmitted -> patience timer
        self.orphans: dict[_Client, TimerHandle] = {}
        #: frames refused by a client's controller (bus-off, FD it cannot send), reported to it
        self.refused = 0
        #: frames of departed clients given up because nobody acknowledged them
        self.expired = 0
        #: see MAX_BACKLOG (set before clients connect); frames dropped for clients that did not read
        self.max_backlog = MAX_BACKLOG
        self.rx_dropped = 0
        self.unix_path = unix_path
        #: the socket file bound (device, inode): removed at close only while it is still that file
        self._bound: Identity = (0, 0)
        if unix_path is not None:
            self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self._bound = bind_unix(self.listener, unix_path)
            except OSError:
                self.listener.close()
                raise
            self.endpoint = f"unix:{unix_path}"
        else:
            self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.listener.bind(("127.0.0.1", tcp_port or 0))
            self.endpoint = f"tcp:127.0.0.1:{self.listener.getsockname()[1]}"
        self.listener.listen(16)
        self.listener.setblocking(False)
        reactor.add_reader(self.listener.fileno(), self._accept)

    def _accept(self) -> None:
        accept_client(self.listener, self.clients, lambda sock, peer: _Client(self, sock, peer), self.reactor)

    def drop(self, client: _Client, reason: str, notify: bool = True, level: int = logging.WARNING) -> None:
        """Disconnect one client with a logged reason; the bus and the other clients carry on.

        Frames the client queued stay on the bus until they are transmitted (a SocketCAN socket
        closed with frames in its device queue leaves them there too): its controller stays
        attached, hears nothing, and is detached when its queue is empty."""
        if client.closed:
            return
        log.log(level if notify else logging.INFO, "bus %s: disconnecting %s: %s", self.bus.name,
                client.peer, reason)
        if notify:
            try:
                client.sock.send(wire.encode_bye(reason))
            except OSError:
                pass
        self.dropped.append(reason)
        client.closed = True
        self.reactor.remove_reader(client.sock.fileno())
        client.outbox.close()
        client.sock.close()
        self.clients.remove(client)
        ctrl = client.controller
        if ctrl is None:
            return
        if ctrl.tx_queue and not ctrl.bus_off:
            ctrl.on_frame = None
            self.orphans[client] = self.bus.clock.call_later(ORPHAN_PATIENCE, self._orphan_check, client,
                                                              client.completed)
        else:
            self.bus.detach(ctrl)

    def orphan_progress(self, client: _Client) -> None:
        """A departed client's frame completed: detach it once its queue is empty."""
        ctrl = client.controller
        if ctrl is not None and not ctrl.tx_queue:
            self._release(client)

    def _orphan_check(self, client: _Client, completed: int) -> None:
        if client not in self.orphans:
            return
        if client.completed == completed:
            self._release(client, "nobody acknowledged them (a lone node? add a second client or "
                                  "`gatewaylab run --acker`)")
        else:
            self.orphans[client] = self.bus.clock.call_later(ORPHAN_PATIENCE, self._orphan_check, client,
                                                              client.completed)

    def _release(self, client: _Client, why: str = "") -> None:
        handle = self.orphans.pop(client, None)
        if handle is not None:
            handle.cancel()
        ctrl = client.controller
        if ctrl is None:
            return
        left = len(ctrl.tx_queue)
        if left and why:
            self.expired += left
            log.warning("bus %s: %d frame(s) queued by departed client %s were not transmitted: %s",
                        self.bus.name, left, client.peer, why)
        self.bus.detach(ctrl)

    def close(self) -> None:
        """Drop every client, stop listening and remove the socket file."""
        for client in list(self.clients):
            self.drop(client, "rig shutting down", level=logging.INFO)
        for client in list(self.orphans):
            self._release(client, "the rig shut down")
        self.reactor.remove_reader(self.listener.fileno())
        self.listener.close()
        if self.unix_path is not None:
            remove_unix(self.unix_path, self._bound)
