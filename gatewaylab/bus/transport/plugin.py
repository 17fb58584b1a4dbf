"""python-can interface ``gatewaylab``: ``can.Bus(interface="gatewaylab", channel=ENDPOINT)``.

Registered in the entry-point group ``can.interface``, so every python-can tool and
``canopen.Network.connect(interface="gatewaylab", channel=...)`` reaches a bus of a running rig
from another process. ENDPOINT is what ``gatewaylab run`` prints: ``unix:/path/to/sock`` or
``tcp:127.0.0.1:PORT``.
"""

from __future__ import annotations

import os
import select
import socket
from collections import deque
from typing import Any

import can
from can.bus import BusState, CanProtocol

from ...common.endpoint import EndpointError, EndpointKind, parse_endpoint
from ...common.errors import GatewaylabError
from .. import wire
from ..frame import CanFrame


def _connect(channel: str, timeout: float) -> socket.socket:
    try:
        ep = parse_endpoint(channel, bare_path=EndpointKind.UNIX)
    except EndpointError as exc:
        raise can.CanInitializationError(str(exc)) from None
    if ep.kind is EndpointKind.UNIX:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        sock.connect(ep.path)
    elif ep.kind is EndpointKind.TCP:
        if not ep.is_local:
            raise can.CanInitializationError(f"gatewaylab endpoints live on this host only, not {ep.host!r}")
        sock = socket.create_connection((ep.host, ep.port), timeout=timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    else:
        raise can.CanInitializationError(f"{channel!r} is not a bus endpoint (unix:PATH or tcp:HOST:PORT)")
    return sock


class GatewaylabBus(can.BusABC):
    """A python-can bus connected to a virtual bus of a running ``gatewaylab run``."""

    def __init__(self, channel: str, receive_own_messages: bool = False, fd: bool = True,
                 name: str = "", connect_timeout: float = 5.0,
                 can_filters: can.typechecking.CanFilters | None = None, **kwargs: Any) -> None:
        if not isinstance(channel, str) or not channel:
            raise can.CanInitializationError("channel must be an endpoint like unix:/path or tcp:127.0.0.1:PORT")
        try:
            self._sock = _connect(channel, connect_timeout)
        except OSError as exc:
            raise can.CanInitializationError(f"cannot connect to gatewaylab bus {channel}: {exc}") from exc
        self._decoder = wire.RecordDecoder()
        self._pending: deque[wire.Record] = deque()
        self._sock.sendall(wire.encode_hello(name or f"python-can-{os.getpid()}", receive_own_messages, fd))
        welcome = self._wait_welcome(connect_timeout)
        self.bus_name = welcome.bus_name
        self.bitrate = welcome.bitrate
        self.data_bitrate = welcome.data_bitrate or None
        self.controller_state = wire.ControllerStateCode.ERROR_ACTIVE
        self.channel_info = f"gatewaylab {welcome.bus_name} via {channel}"
        self._sock.settimeout(None)
        self._sock.setblocking(False)
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD if (welcome.fd and fd) else CanProtocol.CAN_20

    def _wait_welcome(self, timeout: float) -> wire.Welcome:
        while True:
            data = self._sock.recv(65536)
            if not data:
                raise can.CanInitializationError("gatewaylab server closed the connection during HELLO")
            try:
                records = self._decoder.feed(data)
            except GatewaylabError as exc:
                raise can.CanInitializationError(f"bad answer from server: {exc}") from exc
            for i, record in enumerate(records):
                if isinstance(record, wire.Welcome):
                    self._pending.extend(records[i + 1:])
                    return record
                if isinstance(record, wire.Bye):
                    raise can.CanInitializationError(f"server refused: {record.reason}")

    def fileno(self) -> int:
        return self._sock.fileno()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            frame = CanFrame.from_message(msg)
        except GatewaylabError as exc:
            raise can.CanOperationError(str(exc)) from exc
        data = wire.encode_frame(frame)
        view = memoryview(data)
        while view:
            try:
                sent = self._sock.send(view)
            except BlockingIOError:
                _, writable, _ = select.select([], [self._sock], [], timeout)
                if not writable:
                    raise can.CanOperationError("send timed out") from None
                continue
            except OSError as exc:
                raise can.CanOperationError(f"connection to the rig lost: {exc}") from exc
            view = view[sent:]

    def _next_record(self) -> wire.Record | None:
        if self._pending:
            return self._pending.popleft()
        return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        while True:
            record = self._next_record()
            while record is not None:
                if isinstance(record, wire.FrameRecord):
                    return record.frame.to_message(record.timestamp, self.bus_name), False
                if isinstance(record, wire.Status):
                    self.controller_state = record.state
                    if record.kind is wire.StatusKind.ERROR_FRAME:
                        return can.Message(timestamp=record.timestamp, is_error_frame=True,
                                           channel=self.bus_name), False
                elif isinstance(record, wire.Bye):
                    raise can.CanOperationError(f"rig closed the connection: {record.reason}")
                record = self._next_record()
            readable, _, _ = select.select([self._sock], [], [], timeout)
            if not readable:
                return None, False
            try:
                data = self._sock.recv(262144)
            except BlockingIOError:
                continue
            except OSError as exc:
                raise can.CanOperationError(f"connection to the rig lost: {exc}") from exc
            if not data:
                raise can.CanOperationError("the rig closed the connection")
            try:
                self._pending.extend(self._decoder.feed(data))
            except GatewaylabError as exc:
                raise can.CanOperationError(f"bad data from the rig: {exc}") from exc
            timeout = 0

    @property
    def state(self) -> BusState:
        if self.controller_state is wire.ControllerStateCode.BUS_OFF:
            return BusState.ERROR
        return BusState.ACTIVE

    @state.setter
    def state(self, new_state: BusState) -> None:
        # python-can tools set ACTIVE by default; listen-only needs a rig-side controller option.
        if new_state is not BusState.ACTIVE:
            raise can.CanOperationError("a gatewaylab bus connection is always active (not listen-only)")

    def shutdown(self) -> None:
        if not self._is_shutdown:
            try:
                self._sock.setblocking(True)
                self._sock.sendall(wire.encode_bye("client shutdown"))
            except OSError:
                pass
            self._sock.close()
        super().shutdown()
