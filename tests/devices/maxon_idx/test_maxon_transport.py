"""pty and TCP transports with pyserial and the host client (IDX guide 2.2, 2.3.1), objects faked."""

from __future__ import annotations

import os

import serial
from maxon_helpers import DictObjects, RunningRig, ScriptedGateway

from gatewaylab.devices.maxon_idx.commands import NmtCommand
from gatewaylab.devices.maxon_idx.protocol import IdxSlave
from gatewaylab.devices.maxon_idx.transport import PtyPort, TcpServer
from gatewaylab.hosts.maxon_idx.client import IdxClient, IdxError

GUIDE_REQUEST = bytes([0x90, 0x02, 0x60, 0x02, 0x01, 0xB0, 0x30, 0x00, 0x2E, 0x62])
GUIDE_RESPONSE = bytes([0x90, 0x02, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x01, 0x90, 0x90, 0x00, 0x00,
                        0x9A, 0x5C])


def _factory(rr: RunningRig, objects: DictObjects, gateway: ScriptedGateway) -> object:
    def make(send: object) -> IdxSlave:
        return IdxSlave(rr.rig.clock, objects, gateway, lambda: 1, send)  # type: ignore[arg-type]
    return make


def _objects() -> DictObjects:
    objects = DictObjects()
    objects.add(0x30B0, 0, (0x9001).to_bytes(4, "little"), size=4)
    objects.add(0x1008, 0, b"emulated IDX over a pseudo terminal " * 20, size=None)
    objects.add(0x6040, 0, bytes(2), size=2)
    return objects


def test_pty_guide_bytes_with_plain_pyserial(realtime_rig: RunningRig) -> None:
    """2.2.8 over a virtual serial port that pyserial opens like a real one: exact reply bytes."""
    rr = realtime_rig
    port = PtyPort(rr.rig, rr.rig.clock, _factory(rr, _objects(), ScriptedGateway()))  # type: ignore[arg-type]
    rr.start()
    try:
        assert port.path.startswith("/dev/pts/") and os.path.exists(port.path)
        with serial.Serial(port.path, 115200, timeout=2) as s:
            s.write(GUIDE_REQUEST)
            assert s.read(len(GUIDE_RESPONSE)) == GUIDE_RESPONSE
            s.write(GUIDE_REQUEST[:4])      # byte stream in pieces
            s.flush()
            s.write(GUIDE_REQUEST[4:])
            assert s.read(len(GUIDE_RESPONSE)) == GUIDE_RESPONSE
        with serial.Serial(port.path, 115200, timeout=2) as s:   # reopen works (no EIO)
            s.write(GUIDE_REQUEST)
            assert s.read(len(GUIDE_RESPONSE)) == GUIDE_RESPONSE
    finally:
        with rr.rig.clock.lock:
            port.close()


def test_pty_client_segmented_and_errors(realtime_rig: RunningRig) -> None:
    """2.1.1.2/2.1.2.2 through the client over the pty, with a realistic 1 ms latency per reply."""
    rr = realtime_rig
    objects = _objects()
    port = PtyPort(rr.rig, rr.rig.clock, _factory(rr, objects, ScriptedGateway()),  # type: ignore[arg-type]
                   latency=0.001)
    rr.start()
    try:
        with IdxClient(port.path) as client:
            assert client.read(1, 0x30B0, 0, "i32") == 0x9001
            assert client.read_segmented(0, 0x1008, 0) == bytes(objects.values[(0x1008, 0)])
            client.write_segmented(0, 0x1008, 0, b"x" * 700)
            assert client.read_segmented(0, 0x1008, 0) == b"x" * 700
            client.write(0, 0x6040, 0, 0x0F, "u16")
            assert objects.values[(0x6040, 0)] == bytearray([0x0F, 0])
            try:
                client.read(0, 0x5000, 0)
            except IdxError as exc:
                assert exc.code == 0x06020000 and exc.name == "Object does not exist error"
            else:
                raise AssertionError("missing object read succeeded")
    finally:
        with rr.rig.clock.lock:
            port.close()


def test_tcp_socket_url(realtime_rig: RunningRig) -> None:
    """2.2.8 bytes over socket://127.0.0.1:PORT; each connection is its own host (2.2.1: the slave
    answers each request on the connection it came from)."""
    rr = realtime_rig
    gateway = ScriptedGateway()
    server = TcpServer(rr.rig, rr.rig.clock, _factory(rr, _objects(), gateway))  # type: ignore[arg-type]
    rr.start()
    try:
        assert server.url.startswith("socket://127.0.0.1:") and server.port > 0
        with serial.serial_for_url(server.url, timeout=2) as s:
            s.write(GUIDE_REQUEST)
            assert s.read(len(GUIDE_RESPONSE)) == GUIDE_RESPONSE
        with IdxClient(server.url) as a, IdxClient(server.url) as b:
            assert a.read(0, 0x30B0, 0) == b.read(0, 0x30B0, 0) == 0x9001
            a.nmt(0, NmtCommand.START_REMOTE_NODE)
        assert gateway.nmt == [(0, 1)]
    finally:
        with rr.rig.clock.lock:
            server.close()


class _Silent:
    def receive(self, data: bytes) -> None:
        pass

    def close(self) -> None:
        pass


def test_client_timeout_when_nothing_answers(realtime_rig: RunningRig) -> None:
    """2.2.8 D: wait for the receive frame "or a timeout"; the client raises IdxTimeout (0x05040000)."""
    from gatewaylab.hosts.maxon_idx.client import IdxTimeout

    rr = realtime_rig
    port = PtyPort(rr.rig, rr.rig.clock, lambda send: _Silent())
    rr.start()
    try:
        with IdxClient(port.path, timeout=0.2) as client:
            try:
                client.read(0, 0x1000, 0)
            except IdxTimeout as exc:
                assert exc.code == 0x05040000 and "ReadObject" in str(exc)
            else:
                raise AssertionError("no timeout")
    finally:
        with rr.rig.clock.lock:
            port.close()


class _StubServer:
    """What a TCP connection needs of its server, without a listening socket or a rig loop."""

    def __init__(self) -> None:
        from gatewaylab.common.clock import SimulatedClock

        self.clock = SimulatedClock()   # unused: latency 0 writes at once
        self.latency = 0.0
        self.connections: set[object] = set()
        self.readers: list[int] = []
        self.sent: list[bytes] = []

    def make_channel(self, send: object) -> _Silent:
        self.send = send
        return _Silent()

    @property
    def reactor(self) -> _StubServer:
        return self

    def remove_reader(self, fd: int) -> None:
        self.readers.append(fd)


def test_tcp_host_not_reading_keeps_its_connection() -> None:
    """2.2.1 "All commands send an answer": a host that sends faster than it reads fills the socket
    buffer; the replies wait (up to 64 KiB) instead of the connection being closed."""
    import socket

    from gatewaylab.devices.maxon_idx.transport.tcp import _Connection

    ours, host = socket.socketpair()
    ours.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    ours.setblocking(False)
    server = _StubServer()
    conn = _Connection(server, ours)  # type: ignore[arg-type]
    reply = GUIDE_RESPONSE * 100
    for _ in range(30):                         # 42 kB of replies, the host reads none of them
        server.send(reply)  # type: ignore[operator]
    assert not conn.closed and conn.tx_bytes < 30 * len(reply) and conn.dropped_bytes == 0
    received = bytearray()
    host.setblocking(False)
    while len(received) < 30 * len(reply):
        try:
            received += host.recv(65536)
        except BlockingIOError:
            conn._flush()                       # what the next readable event does
    assert bytes(received) == reply * 30
    conn.close()
    host.close()


def test_rig_file_usb_settings_are_checked() -> None:
    """2.3.1 USB port, emulated by the rig file's usb table: a TCP port outside 0..65535, a negative
    latency or an unknown key is a ConfigError naming the device, not a traceback from bind()."""
    import pytest

    from gatewaylab.common.clock import RealTimeClock
    from gatewaylab.common.errors import ConfigError
    from gatewaylab.rig.config import parse_rig
    from gatewaylab.rig.runtime import Rig

    for usb, message in (({"tcp_port": 70000}, "tcp_port must be 0..65535"),
                         ({"tcp_port": "x"}, "tcp_port must be 0..65535"),
                         ({"latency_ms": -1}, "latency_ms must be a number >= 0"),
                         ({"pyt": True}, "unknown usb keys")):
        with pytest.raises(ConfigError, match=message):
            Rig(parse_rig({"clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}],
                           "device": [{"kind": "maxon_idx", "name": "idx1", "bus": "can0", "node_id": 1,
                                       "usb": usb}]}), clock=RealTimeClock(), endpoints=False)
