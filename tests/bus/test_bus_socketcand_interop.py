"""socketcand clients we did not write against `gatewaylab run` (issue 24, socketcand server): python-can's
own ``interface="socketcand"``, python ``canopen`` over it (SDO 0x1008 and a SYNC/RPDO/TPDO loop with a
drive), CAN FD and errors as socketcand sends them (linux-can/socketcand doc/protocol.md, state_raw.c),
and clients that misbehave while the rig and the other clients carry on."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest
from csp_loop_kit import csp_loop
from socketcand_kit import RawClient

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
data_bitrate = 5000000
socketcand = true

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
"""


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    folder = tmp_path_factory.mktemp("socketcand")
    rig_file = folder / "rig.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, workdir=folder, timeout=60) as process:
        yield process


def port(rig: RigProcess) -> int:
    value = rig.info["buses"]["can0"]["socketcand"]
    assert isinstance(value, int) and value > 0
    return value


def socketcand_bus(rig: RigProcess) -> can.BusABC:
    return can.Bus(interface="socketcand", host="127.0.0.1", port=port(rig), channel="can0")


def recv_id(bus: can.BusABC, can_id: int, timeout: float = 10.0) -> can.Message:
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = bus.recv(left)
        if msg is not None and msg.arbitration_id == can_id and not msg.is_error_frame:
            return msg
    raise AssertionError(f"no frame 0x{can_id:X} within {timeout} s")


def test_python_can_socketcand_exchanges_classic_frames(rig: RigProcess) -> None:
    """python-can's socketcand interface handshakes ('< hi >', open, rawmode) unchanged and carries 11- and
    29-bit frames both ways; timestamps are Unix time of the rig's bus (protocol.md '< frame ID sec.usec >')."""
    a, b = socketcand_bus(rig), socketcand_bus(rig)
    try:
        before = time.time()
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02\x03", is_extended_id=False))
        got = recv_id(b, 0x123)
        assert bytes(got.data) == b"\x01\x02\x03" and not got.is_extended_id
        assert before - 1 <= got.timestamp <= time.time() + 1
        b.send(can.Message(arbitration_id=0x1ABCDE01, data=bytes(8), is_extended_id=True))
        got = recv_id(a, 0x1ABCDE01)
        assert got.is_extended_id and bytes(got.data) == bytes(8)
    finally:
        a.shutdown()
        b.shutdown()


def test_handshake_holds_on_a_busy_bus(rig: RigProcess) -> None:
    """python-can reads the answer to '< rawmode >' with one recv(256) and wants exactly '< ok >': while
    another client keeps the bus busy (a frame every 0.5 ms), ten connections in a row all succeed
    (the server holds frames briefly after '< ok >', docs/decisions.md)."""
    flood = can.Bus(interface="gatewaylab", channel=rig.endpoint("can0"))
    task = flood.send_periodic(can.Message(arbitration_id=0x7F1, data=bytes(8), is_extended_id=False), 0.0005)
    try:
        for _ in range(10):
            bus = socketcand_bus(rig)
            try:
                assert recv_id(bus, 0x7F1).arbitration_id == 0x7F1
            finally:
                bus.shutdown()
    finally:
        task.stop()
        flood.shutdown()


def test_canopen_reads_1008_and_runs_a_pdo_loop(rig: RigProcess) -> None:
    """CiA 301 SDO upload of 0x1008 (segmented) and a CiA 402 CSP loop: RPDO1 + SYNC out, TPDO1 (type 1)
    back each cycle, all through python-can's socketcand interface."""
    logging.getLogger("canopen").setLevel(logging.ERROR)
    eds = rig.info["canopen"]["can0"]["axis2"]["eds"]
    network = canopen.Network(socketcand_bus(rig))
    network.connect()
    try:
        node = network.add_node(2, eds)
        assert "gatewaylab" in node.sdo[0x1008].raw
        cycles = 200
        received, start, _ = csp_loop(network, node, cycles)
        assert received >= cycles - 5, f"{received} of {cycles} TPDOs"
        sw = node.tpdo[1]["Statusword"].raw
        assert sw & 0x6F == 0x27                      # operation enabled
        assert node.tpdo[1]["Position actual value"].raw > start + 40 * cycles // 2
    finally:
        network.disconnect()


def test_can_fd_frames_both_ways(rig: RigProcess) -> None:
    """CAN FD in RAW mode: '< fdsend ID FLAGS LEN b ... >' in, '< fdframe ID FLAGS sec.usec DATA >' out
    (socketcand PR 33) to a client that asked for CAN FD ('< rawmode fd >')."""
    sender, listener = RawClient(port(rig)), RawClient(port(rig))
    try:
        sender.open_raw()
        listener.open_raw(fd=True)
        data = bytes(range(64))
        sender.send(b"< fdsend 0000ABCD 1 64 " + " ".join(f"{x:x}" for x in data).encode() + b" >")
        line = listener.expect(b" >").split(b"< fdframe ", 1)[1]
        ident, flags, stamp, payload = line[:-2].split(b" ")
        assert (ident, flags, payload) == (b"0000ABCD", b"01", data.hex().upper().encode())
        assert abs(float(stamp) - time.time()) < 60
        sender.send(b"< sendfd 321 12 " + b"aa " * 12 + b">")
        line = listener.expect(b" >").split(b"< fdframe ", 1)[1]
        assert line.startswith(b"321 00 ") and line.endswith(b" " + b"AA" * 12 + b" >")
    finally:
        sender.close()
        listener.close()


def test_echo_and_errors_as_socketcand_sends_them(rig: RigProcess) -> None:
    """'< echo >' comes back; an unknown command gets '< error unknown command >' and the connection
    stays; opening a bus the server does not have gets '< error could not open bus >' and the end."""
    c = RawClient(port(rig))
    try:
        c.open_raw()
        c.send(b"< echo >")
        c.expect(b"< echo >")
        c.send(b"< frobnicate 1 2 >")
        c.expect(b"< error unknown command >")
        c.send(b"< echo >")
        c.expect(b"< echo >")
    finally:
        c.close()
    bad = RawClient(port(rig))
    try:
        bad.expect(b"< hi >")
        bad.send(b"< open vcan9 >")
        bad.expect(b"< error could not open bus >")
        assert bad.closed_by_peer()
    finally:
        bad.close()


def test_misbehaving_clients_leave_the_rig_and_other_clients_alone(rig: RigProcess, tmp_path: Path) -> None:
    """A client vanishing mid-element, one sending garbage lines and one that never reads (a full socket
    buffer) while 2000 frames pass: a well-behaved python-can client gets every frame, the rig runs on."""
    good = socketcand_bus(rig)
    vanish, garbage, slow = RawClient(port(rig)), RawClient(port(rig)), RawClient(port(rig), rcvbuf=4096)
    sender = socketcand_bus(rig)
    try:
        vanish.open_raw()
        vanish.send(b"< send 7FF 2 11")
        vanish.close()                                    # gone in the middle of an element
        garbage.open_raw()
        garbage.send(b"GET / HTTP/1.1\r\n\r\n< send zz 1 >\n< bogus >\n\x00\xff<<>>")
        garbage.expect(b"< error unknown command >")
        slow.open_raw()                                   # and never reads again
        count = 2000
        for i in range(count):
            sender.send(can.Message(arbitration_id=0x300 + (i % 16), data=i.to_bytes(4, "little"),
                                    is_extended_id=False))
        got: list[int] = []
        deadline = time.monotonic() + 60
        while len(got) < count and time.monotonic() < deadline:
            msg = good.recv(5.0)
            if msg is None:
                break
            if 0x300 <= msg.arbitration_id < 0x310:
                got.append(int.from_bytes(msg.data, "little"))
        assert got == list(range(count))
        assert rig.proc.poll() is None
        late = socketcand_bus(rig)                        # a new client still gets served
        late.send(can.Message(arbitration_id=0x555, data=b"\x55", is_extended_id=False))
        assert bytes(recv_id(good, 0x555).data) == b"\x55"
        late.shutdown()
    finally:
        for c in (garbage, slow):
            c.close()
        good.shutdown()
        sender.shutdown()
    assert rig.proc.poll() is None
    assert "Traceback" not in rig.log_text()


def test_cli_option_serves_every_bus(tmp_path: Path) -> None:
    """`gatewaylab run --socketcand` serves each bus (no rig key needed); the port is in the ready file as
    buses.NAME.socketcand, on 127.0.0.1 only."""
    rig_file = tmp_path / "two.toml"
    rig_file.write_text('clock = "realtime"\n[[bus]]\nname = "can0"\n[[bus]]\nname = "can1"\nendpoint = "none"\n')
    with RigProcess(rig_file, "--socketcand", "--acker", workdir=tmp_path, timeout=60) as process:
        ports = {name: bus["socketcand"] for name, bus in process.info["buses"].items()}
        assert set(ports) == {"can0", "can1"} and len(set(ports.values())) == 2
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=ports["can1"], channel="can1")
        bus.shutdown()
        c = RawClient(ports["can0"])
        try:
            c.expect(b"< hi >")
            c.send(b"< open can1 >")                       # each port serves its own bus
            c.expect(b"< error could not open bus >")
        finally:
            c.close()


def test_python_can_client_on_a_can_fd_bus(rig: RigProcess, caplog: pytest.LogCaptureFixture) -> None:
    """python-can's socketcand client cannot parse '< fdframe >' (it logged "Could not parse ascii message"
    for each): it gets none, only the classic frames between them; its FD message (12 bytes, sent as
    '< send ID C ... >') reaches the bus as a CAN FD frame. A raw client that did not ask gets no fdframe."""
    client = socketcand_bus(rig)
    raw = RawClient(port(rig))
    native = can.Bus(interface="gatewaylab", channel=rig.endpoint("can0"))
    try:
        raw.open_raw()
        with caplog.at_level(logging.WARNING, logger="can"):
            for i in range(20):
                native.send(can.Message(arbitration_id=0x210, data=bytes(range(i, i + 16)), is_fd=True,
                                        is_extended_id=False))
            native.send(can.Message(arbitration_id=0x211, data=b"\x11", is_extended_id=False))
            got = recv_id(client, 0x211)
            assert bytes(got.data) == b"\x11"
            client.send(can.Message(arbitration_id=0x212, data=bytes(range(12)), is_fd=True, is_extended_id=False))
            fd = recv_id(native, 0x212)
            assert fd.is_fd and bytes(fd.data) == bytes(range(12))
        assert not [r for r in caplog.records if "Could not parse" in r.getMessage()]
        seen = raw.expect(b"< frame 211 ")
        assert b"fdframe" not in seen and b"< frame 211 " in seen
    finally:
        raw.close()
        client.shutdown()
        native.shutdown()
