"""End to end: pymodbus's own ModbusTcpClient -> `gatewaylab run` (a child process) -> the Modbus TCP
gateway -> SDO on the virtual bus -> a CiA 402 drive (CiA 402 power state machine and profile
position mode; Modbus Application Protocol V1.1b3 section 7 exceptions)."""

from __future__ import annotations

import signal
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from gatewaylab.rig.process import RigProcess, RigStartTimeout

RIG = """
[[bus]]
name = "can0"
bitrate = 1000000

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002

[[device]]
kind = "modbus_gateway"
name = "mb1"
bus = "can0"
node_id = 100
tcp_port = {port}
nodes = [2, 5]
"""


def _port(info: dict[str, object]) -> int:
    endpoint = info["modbus"]["mb1"]  # type: ignore[index]
    assert isinstance(endpoint, str) and endpoint.startswith("tcp:127.0.0.1:")
    return int(endpoint.rsplit(":", 1)[1])


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    tmp = tmp_path_factory.mktemp("modbus")
    rig_file = tmp / "rig.toml"
    rig_file.write_text(RIG.format(port=0))
    with RigProcess(rig_file, workdir=tmp, timeout=60) as r:
        yield r


@pytest.fixture
def client(rig: RigProcess) -> Iterator[ModbusTcpClient]:
    c = ModbusTcpClient("127.0.0.1", port=_port(rig.info), timeout=5)
    assert c.connect()
    yield c
    c.close()


def _status(c: ModbusTcpClient) -> int:
    r = c.read_input_registers(0, count=1, device_id=2)
    assert not r.isError(), r
    return int(r.registers[0])


def _i32(words: list[int]) -> int:
    value = (words[0] << 16) | words[1]
    return value - (1 << 32) if value & 0x80000000 else value


def test_operation_enabled_and_profile_position_move(client: ModbusTcpClient) -> None:
    """CiA 402: controlword 0x06 / 0x07 / 0x0F through holding register 0 walks the power state
    machine to Operation Enabled (statusword & 0x6F = 0x27, input register 0); modes of operation 1
    (profile position, holding 1), target position (holding 2-3, high word first), new set point
    (controlword bit 4): the actual position (input registers 2-3) follows to the target and
    statusword bit 10 'target reached' is set."""
    c = client
    expected = {0x06: 0x21, 0x07: 0x23, 0x0F: 0x27}
    for cw, pattern in expected.items():
        r = c.write_register(0, cw, device_id=2)
        assert not r.isError(), r
        assert _status(c) & 0x6F == pattern
    assert not c.write_register(1, 1, device_id=2).isError()
    assert c.read_input_registers(1, count=1, device_id=2).registers == [1]
    target = 30_000
    assert not c.write_registers(6, [0x0006, 0x4000], device_id=2).isError()      # profile velocity 409600
    assert not c.write_registers(2, [target >> 16, target & 0xFFFF], device_id=2).isError()
    assert c.read_holding_registers(2, count=2, device_id=2).registers == [target >> 16, target & 0xFFFF]
    assert not c.write_register(0, 0x1F, device_id=2).isError()                   # new set point
    assert not c.write_register(0, 0x0F, device_id=2).isError()
    positions: list[int] = []
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        r = c.read_input_registers(0, count=4, device_id=2)
        assert not r.isError(), r
        positions.append(_i32(r.registers[2:4]))
        if r.registers[0] & 0x400 and abs(positions[-1] - target) <= 10:    # inside the position window
            break
    assert abs(positions[-1] - target) <= 10, positions[-10:]
    on_the_way = {p for p in positions if 0 < p < target - 10}
    assert len(on_the_way) > 2, positions[:10]                             # followed on its way, not only at the end
    assert min(positions) >= -10 and max(positions) <= target + 500, (min(positions), max(positions))


def test_exceptions_seen_by_the_client(client: ModbusTcpClient) -> None:
    """Modbus 7: an unmapped register -> 02 illegal data address; node 5 is served but not on the
    bus -> 0B gateway target device failed to respond; unit 9 is not served -> 0A gateway path
    unavailable; coils do not exist -> 01 illegal function."""
    r = client.read_holding_registers(50, count=1, device_id=2)
    assert r.isError() and r.exception_code == 0x02
    r = client.read_holding_registers(0, count=1, device_id=5)
    assert r.isError() and r.exception_code == 0x0B
    r = client.read_holding_registers(0, count=1, device_id=9)
    assert r.isError() and r.exception_code == 0x0A
    r = client.read_coils(0, count=1, device_id=2)
    assert r.isError() and r.exception_code == 0x01
    r = client.write_register(2, 1, device_id=2)                 # half of the 32-bit target position
    assert r.isError() and r.exception_code == 0x02


def test_garbage_on_one_connection_does_not_stop_the_server(rig: RigProcess, client: ModbusTcpClient) -> None:
    """A peer that sends bytes that are no Modbus TCP frames (bad MBAP protocol id, junk) does not
    take the server down: another client is served before and after."""
    assert _status(client) & 0x40 or _status(client) & 0x27
    with socket.create_connection(("127.0.0.1", _port(rig.info)), timeout=5) as junk:
        junk.sendall(b"\xde\xad\xbe\xef" * 64 + bytes(range(256)))
        junk.sendall(bytes([0, 1, 0x12, 0x34, 0, 6, 2, 3, 0, 0, 0, 1]))      # protocol id 0x1234
        r = client.read_input_registers(0, count=1, device_id=2)
        assert not r.isError(), r
    with ModbusTcpClient("127.0.0.1", port=_port(rig.info), timeout=5) as second:
        assert not second.read_input_registers(0, count=1, device_id=2).isError()


def test_sigterm_stops_cleanly_and_a_port_in_use_fails_the_start(tmp_path: Path) -> None:
    """docs/architecture.md life cycle: SIGTERM ends the rig with exit 0 and the Modbus port closed,
    also with a client still connected;
    a second rig asking for a port in use does not start (exit 1, one line naming the section)."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG.format(port=0))
    first = RigProcess(rig_file, workdir=tmp_path, timeout=60)
    plc = ModbusTcpClient("127.0.0.1", port=_port(first.info), timeout=5)
    try:
        port = _port(first.info)
        assert plc.connect() and not plc.read_input_registers(0, count=1, device_id=2).isError()  # stays connected
        busy = tmp_path / "busy.toml"
        busy.write_text(RIG.format(port=port))
        with pytest.raises(RigStartTimeout, match=r"modbus_gateway|mb1") as exc:
            RigProcess(busy, workdir=tmp_path, timeout=60)
        assert "Traceback" not in str(exc.value)
    finally:
        first.proc.send_signal(signal.SIGTERM)
        code = first.proc.wait(20)
        first.stop()
        plc.close()
    assert code == 0, first.log_text()
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
