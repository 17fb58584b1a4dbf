"""The Modbus TCP gateway of a running rig through pymodbus, as a PLC or HMI program uses it (issue 21, "The
user's path as a suite"; docs/devices/modbus_gateway.md): the endpoint from the ready file's ``modbus``,
unit id = CANopen node id, the default CiA 402 register map. The happy path (garbage is another module's):
the first answer after connecting (< 1 s), the steady state of an HMI's cyclic poll (p99 of request ->
answer), writes of 32-bit objects (high word first) to two drives, seen as SDO downloads by a python-can
listener on the CAN endpoint of the same rig and read back through Modbus.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import can
import pytest
from pymodbus.client import ModbusTcpClient
from userpath_kit import RIG_TWO_DRIVES, Latencies, measured

from gatewaylab.rig.process import RigProcess

RIG = RIG_TWO_DRIVES + """
[[device]]
kind = "modbus_gateway"
name = "plc"
bus = "can0"
node_id = 100
tcp_port = 0
nodes = [2, 3]
"""


@pytest.fixture(scope="module")
def rig(start_rig: Callable[..., RigProcess]) -> RigProcess:
    return start_rig(RIG)


def address(rig: RigProcess) -> tuple[str, int]:
    """The ready file's ``"modbus": {"plc": "tcp:127.0.0.1:PORT"}``."""
    host, port = str(rig.info["modbus"]["plc"]).removeprefix("tcp:").rsplit(":", 1)
    return host, int(port)


@pytest.fixture
def plc(rig: RigProcess) -> Iterator[ModbusTcpClient]:
    host, port = address(rig)
    with ModbusTcpClient(host, port=port, timeout=5) as client:
        yield client


@measured
def test_first_answer_after_connect_and_cyclic_poll(rig: RigProcess) -> None:
    """Modbus Application Protocol V1.1b3 6.4 (FC 4, read input registers): statusword, mode display and the
    32-bit position actual value of drive 2 (input registers 0-3). The first answer after connecting within a
    second; then an HMI's cyclic poll (every 2 ms) of both drives: p99 of request -> answer."""
    host, port = address(rig)
    started = time.time()
    with ModbusTcpClient(host, port=port, timeout=5) as client:
        first = client.read_input_registers(0, count=4, device_id=2)
        lat = Latencies("Modbus FC 4 (4 registers = 3 SDO uploads)")
        lat.first = time.time() - started
        assert not first.isError(), first
        assert first.registers[0] & 0x4F == 0x40            # CiA 402 'switch on disabled' after power-on
        for i in range(200):
            asked = time.time()
            r = client.read_input_registers(0, count=4, device_id=2 + i % 2)
            lat.add(time.time() - asked)
            assert not r.isError(), r
            time.sleep(0.002)                               # the HMI's cycle
    lat.check()


def test_writes_are_sdo_downloads_on_the_bus_and_read_back(rig: RigProcess, plc: ModbusTcpClient) -> None:
    """docs/devices/modbus_gateway.md default map: holding 6-7 = 0x6081 profile velocity (u32, high word
    first; FC 16) and holding 2-3 = 0x607A target position (i32). Written through Modbus to drives 2 and 3:
    a python-can listener on the rig's CAN endpoint sees each write as an SDO download (CiA 301 7.2.4.3.3:
    initiate download, index, sub-index, the value little-endian) to that node and the drive's confirmation;
    read back through Modbus (pymodbus's convert_from_registers, word_order "big"). (A second SDO client --
    python canopen -- is not used: it would share the drives' one SDO server channel with the gateway.)"""
    values = {2: (12_345, -20_000), 3: (54_321, 7_000)}
    with can.Bus(interface="gatewaylab", channel=rig.info["buses"]["can0"]["endpoint"]) as bus:
        reader = can.BufferedReader()
        notifier = can.Notifier(bus, [reader])
        try:
            for node, (velocity, target) in values.items():
                words = plc.convert_to_registers(velocity, plc.DATATYPE.UINT32, word_order="big")
                assert not plc.write_registers(6, words, device_id=node).isError()
                words = plc.convert_to_registers(target, plc.DATATYPE.INT32, word_order="big")
                assert not plc.write_registers(2, words, device_id=node).isError()
            frames: list[can.Message] = []
            deadline = time.monotonic() + 10
            while len([m for m in frames if m.arbitration_id in (0x582, 0x583) and m.data[0] == 0x60]) < 4:
                assert time.monotonic() < deadline, frames
                msg = reader.get_message(1.0)
                if msg is not None:
                    frames.append(msg)
        finally:
            notifier.stop()
    for node, (velocity, target) in values.items():
        downloads = [(int.from_bytes(m.data[1:3], "little"), m.data[3], bytes(m.data[4:8]))
                     for m in frames if m.arbitration_id == 0x600 + node and m.data[0] & 0xE0 == 0x20]
        assert downloads == [(0x6081, 0, velocity.to_bytes(4, "little")),
                             (0x607A, 0, target.to_bytes(4, "little", signed=True))]
        confirmed = [int.from_bytes(m.data[1:3], "little") for m in frames
                     if m.arbitration_id == 0x580 + node and m.data[0] == 0x60]
        assert confirmed == [0x6081, 0x607A]
        r = plc.read_holding_registers(2, count=6, device_id=node)
        assert not r.isError(), r
        assert plc.convert_from_registers(r.registers[0:2], plc.DATATYPE.INT32, word_order="big") == target
        assert plc.convert_from_registers(r.registers[4:6], plc.DATATYPE.UINT32, word_order="big") == velocity
