"""A socketcand server for one virtual bus on 127.0.0.1 (the protocol: :mod:`gatewaylab.bus.socketcand`).

Each connection that opens the bus becomes one controller on it. Like :mod:`.server` it runs in the
rig runtime's loop (callbacks hold ``clock.lock``) through the same :class:`~.server.Reactor`; a
client that stops reading is disconnected when its backlog passes ``max_backlog``, a client that
sends garbage gets socketcand's answers, and neither disturbs the bus or the other clients.
"""

from __future__ import annotations

import logging
import socket

from gatewaylab.bus import socketcand as sc
from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import BusEvent, Controller, ErrorFrameEvent, ErrorKind, ErrorState, StateChangeEvent
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.transport.outbox import Outbox, accept_client, receive
from gatewaylab.bus.transport.server import Reactor
from gatewaylab.common.clock import PeriodicTimer, TimerHandle
from gatewaylab.common.errors import LocalError

log = logging.getLogger(__name__)

#: unread output a client may pile up before it is disconnected (about 30 000 frames)
MAX_BACKLOG = 1024 * 1024
#: After ``< rawmode >`` is answered, frames wait this long (clock time) before they follow the
#: ``< ok >``: python-can's client reads the answer with one ``recv(256)`` and requires it to be
#: exactly ``< ok >``, so a frame in the same read would fail its handshake (docs/decisions.md).
RAW_SETTLE = 0.1


def error_class(ev: ErrorFrameEvent | StateChangeEvent) -> int:
    """The linux/can/error.h class of a bus event, as a SocketCAN raw socket reports it."""
    if isinstance(ev, ErrorFrameEvent):
        kind = sc.CAN_ERR_ACK if ev.kind is ErrorKind.ACK else sc.CAN_ERR_PROT
        return kind | sc.CAN_ERR_BUSERROR
    if ev.new is ErrorState.BUS_OFF:
        return sc.CAN_ERR_BUSOFF
    if ev.old is ErrorState.BUS_OFF:
        return sc.CAN_ERR_RESTARTED
    return sc.CAN_ERR_CRTL


class _Client:
    def __init__(self, server: SocketcandServer, sock: socket.socket, peer: str) -> None:
        self.server = server
        self.sock = sock
        self.peer = peer
        self.session = sc.Session((server.bus.name,))
        self.controller: Controller | None = None
        self.outbox = Outbox(sock, server.reactor, server.max_backlog, self._send_failed, self._overflow)
        self.closed = False
        #: RAW mode: frames held until the settle timer after ``< ok >`` fires
        self.held: list[bytes] | None = None
        self.settle: TimerHandle | None = None
        #: BCM mode: cyclic send jobs and subscriptions by (can_id, extended)
        self.jobs: dict[tuple[int, bool], tuple[CanFrame, PeriodicTimer | None]] = {}
        self.subs: dict[tuple[int, bool], float] = {}
        self.last_sent: dict[tuple[int, bool], float] = {}
        self.pending: dict[tuple[int, bool], TimerHandle] = {}
        #: FD frames not sent because the client did not ask for CAN FD
        self.fd_withheld = 0

    # -- bus -> client -----------------------------------------------------------------------
    def on_frame(self, frame: CanFrame, t: float) -> None:
        epoch = self.server.bus.clock.wall_epoch
        if self.session.mode is sc.Mode.RAW:
            if frame.rtr:
                self.server.rtr_skipped += 1   # upstream state_raw.c: "TODO implement"
                return
            if frame.fd and not self.session.fd:
                self._withhold()
                return
            self.emit(sc.raw_frame(frame, epoch + t))
            return
        key = (frame.can_id, frame.extended)
        interval = self.subs.get(key)
        if interval is None or frame.fd or frame.rtr:
            return
        if interval and t - self.last_sent.get(key, -interval) < interval:
            # throttled (BCM RX_SETUP ival2): the newest frame goes out when the interval ends
            old = self.pending.pop(key, None)
            if old is not None:
                old.cancel()
            due = self.last_sent[key] + interval
            self.pending[key] = self.server.bus.clock.call_at(due, self._throttled, key, frame, due)
            return
        self.last_sent[key] = t
        self.emit(sc.bcm_frame(frame, epoch + t))

    def _withhold(self) -> None:
        """An FD frame for a client that did not ask for CAN FD: counted, said once per client."""
        self.fd_withheld += 1
        self.server.fd_withheld += 1
        if self.fd_withheld == 1:
            log.warning("bus %s: socketcand %s did not ask for CAN FD: FD frames are not sent to it (a client "
                        "that parses '< fdframe >' sends '< rawmode fd >'; python-can's client cannot)",
                        self.server.bus.name, self.peer)

    def _throttled(self, key: tuple[int, bool], frame: CanFrame, t: float) -> None:
        self.pending.pop(key, None)
        if key in self.subs and not self.closed:
            self.last_sent[key] = t
            self.emit(sc.bcm_frame(frame, self.server.bus.clock.wall_epoch + t))

    def on_event(self, ev: BusEvent) -> None:
        if self.session.mode is sc.Mode.RAW and isinstance(ev, (ErrorFrameEvent, StateChangeEvent)):
            self.emit(sc.error_frame(error_class(ev), self.server.bus.clock.wall_epoch + ev.timestamp))

    def emit(self, data: bytes) -> None:
        if self.held is not None:
            self.held.append(data)
        else:
            self.write(data)

    def _settled(self) -> None:
        held, self.held, self.settle = self.held or [], None, None
        if held:
            self.write(b"".join(held))

    def write(self, data: bytes) -> None:
        if not self.closed:
            self.outbox.write(data)

    def _send_failed(self, exc: OSError) -> None:
        self.server.drop(self, f"send failed: {exc}", level=logging.INFO)

    def _overflow(self, size: int) -> None:
        self.server.drop(self, f"client does not read: {size} bytes backlog")

    # -- client -> bus -----------------------------------------------------------------------
    def readable(self) -> None:
        data = receive(self.sock)
        if data is None:
            return
        if isinstance(data, OSError):
            self.server.drop(self, f"receive failed: {data}", level=logging.INFO)
            return
        if not data:
            self.server.drop(self, "client closed the connection", level=logging.INFO)
            return
        for ev in self.session.feed(data):
            self.handle(ev)
            if self.closed:
                return

    def handle(self, ev: sc.Event) -> None:
        server = self.server
        if isinstance(ev, sc.Reply):
            self.write(ev.data)
        elif isinstance(ev, sc.SendFrame):
            self.send(ev.frame)
        elif isinstance(ev, sc.ModeChanged):
            self.stop_timers()
            held, self.held = self.held, None
            if held:
                self.write(b"".join(held))
            if ev.mode is sc.Mode.RAW and not self.closed:
                self.held = []
                self.settle = server.bus.clock.call_later(RAW_SETTLE, self._settled)
        elif isinstance(ev, sc.Opened):
            self.controller = server.bus.attach(f"socketcand {self.peer}", on_frame=self.on_frame,
                                                on_event=self.on_event)
        elif isinstance(ev, sc.AddJob):
            self._delete((ev.frame.can_id, ev.frame.extended))
            timer = None
            if ev.interval > 0:
                timer = server.bus.clock.call_every(ev.interval, self._job, (ev.frame.can_id, ev.frame.extended),
                                                    first=0.0)
            else:
                self.send(ev.frame)
            self.jobs[ev.frame.can_id, ev.frame.extended] = (ev.frame, timer)
        elif isinstance(ev, sc.UpdateJob):
            key = (ev.frame.can_id, ev.frame.extended)
            if key in self.jobs:
                self.jobs[key] = (ev.frame, self.jobs[key][1])
        elif isinstance(ev, sc.DeleteJob):
            self._delete((ev.can_id, ev.extended))
        elif isinstance(ev, sc.Subscribe):
            self.subs[ev.can_id, ev.extended] = ev.interval
        elif isinstance(ev, sc.Unsubscribe):
            self.subs.pop((ev.can_id, ev.extended), None)
            handle = self.pending.pop((ev.can_id, ev.extended), None)
            if handle is not None:
                handle.cancel()
        elif isinstance(ev, sc.SyntaxErrorEvent):
            server.syntax_errors += 1
            log.info("bus %s: socketcand %s: syntax error in %s command: %s", server.bus.name, self.peer,
                     ev.command, ev.message)
        elif isinstance(ev, sc.Close):
            if ev.data:
                self.write(ev.data)
            server.drop(self, ev.reason)

    def send(self, frame: CanFrame) -> None:
        ctrl = self.controller
        assert ctrl is not None   # the session sends frames only after open
        try:
            ctrl.send(frame)
        except LocalError as exc:   # bus-off, an FD frame on a classic bus: refused, connection stays
            self.server.refused += 1
            log.info("bus %s: socketcand %s: frame refused: %s", self.server.bus.name, self.peer, exc)

    def _job(self, key: tuple[int, bool]) -> None:
        job = self.jobs.get(key)
        if job is not None and not self.closed:
            self.send(job[0])

    def _delete(self, key: tuple[int, bool]) -> None:
        job = self.jobs.pop(key, None)
        if job is not None and job[1] is not None:
            job[1].cancel()

    def stop_timers(self) -> None:
        """socketcand closes the BCM socket on a mode switch: its jobs and subscriptions end."""
        for key in list(self.jobs):
            self._delete(key)
        self.subs.clear()
        for handle in self.pending.values():
            handle.cancel()
        self.pending.clear()
        if self.settle is not None:
            self.settle.cancel()
        self.settle = None


class SocketcandServer:
    """Serves one virtual bus to socketcand clients on 127.0.0.1:``port`` (0: a free port)."""

    def __init__(self, bus: VirtualBus, reactor: Reactor, port: int = 0, *,
                 max_backlog: int = MAX_BACKLOG) -> None:
        self.bus = bus
        self.reactor = reactor
        self.max_backlog = max_backlog
        self.clients: list[_Client] = []
        self.dropped: list[str] = []
        self.syntax_errors = 0
        self.refused = 0
        self.rtr_skipped = 0
        #: FD frames not sent to clients that did not ask for CAN FD (all clients)
        self.fd_withheld = 0
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.listener.bind(("127.0.0.1", port))
            self.listener.listen(16)
            self.listener.setblocking(False)
        except OSError:
            self.listener.close()
            raise
        self.port: int = self.listener.getsockname()[1]
        reactor.add_reader(self.listener.fileno(), self._accept)

    def _accept(self) -> None:
        client = accept_client(self.listener, self.clients, lambda sock, peer: _Client(self, sock, peer),
                               self.reactor)
        if client is not None:
            client.write(sc.Session.greeting())

    def drop(self, client: _Client, reason: str, level: int = logging.WARNING) -> None:
        """Disconnect one client with a logged reason; the bus and the other clients carry on."""
        if client.closed:
            return
        log.log(level, "bus %s: socketcand: disconnecting %s: %s", self.bus.name, client.peer, reason)
        if client.fd_withheld:
            log.info("bus %s: socketcand %s: %d CAN FD frame(s) were not sent to it (it did not ask for CAN FD)",
                     self.bus.name, client.peer, client.fd_withheld)
        client.held = None
        client.stop_timers()
        if client.outbox.out:   # a last answer (an error before the end) goes out if it fits
            try:
                client.sock.send(client.outbox.out)
            except OSError:
                pass
        client.closed = True
        self.dropped.append(reason)
        self.reactor.remove_reader(client.sock.fileno())
        client.outbox.close()
        client.sock.close()
        self.clients.remove(client)
        if client.controller is not None:
            self.bus.detach(client.controller)

    def close(self) -> None:
        """Drop every client and stop listening."""
        for client in list(self.clients):
            self.drop(client, "rig shutting down", level=logging.INFO)
        self.reactor.remove_reader(self.listener.fileno())
        self.listener.close()
