"""python-can over the esd CAN-EtherCAT (issue 12 'python-can on top'): canopen's Network through
``can.Bus(interface="esd_can_ethercat")`` reads and moves a CiA 402 drive behind the gateway, in
process on a simulated clock (manual 5.1.5: the counter handshake carries every frame)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.canopen.drive import Drive
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canhost import EthercatHost
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway
from gatewaylab.ethercat.backend import InProcessBackend
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.master import Master
from gatewaylab.ethercat.segment import Segment

RIG = """
[[bus]]
name = "can0"
bitrate = 500000

[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
"""
NODE = 2


def _u32(v: int) -> bytes:
    return struct.pack("<I", v)


def move_pp(node: canopen.RemoteNode, host: EthercatHost, target: int) -> tuple[int, int]:
    """CiA 402 by SDO only: profile position mode (0x6060 = 1), shutdown / switch on / enable
    (0x6040 = 6, 7, 0x0F), target 0x607A, new set-point (0x1F then 0x0F); 2 s later returns
    (0x6064 position actual value, 0x6041 statusword)."""
    sdo = node.sdo
    sdo.download(0x6060, 0, b"\x01")
    for cw in (0x06, 0x07, 0x0F):
        sdo.download(0x6040, 0, struct.pack("<H", cw))
    assert struct.unpack("<H", sdo.upload(0x6041, 0))[0] & 0x6F == 0x27   # operation enabled
    sdo.download(0x607A, 0, struct.pack("<i", target))
    sdo.download(0x6040, 0, struct.pack("<H", 0x1F))
    sdo.download(0x6040, 0, struct.pack("<H", 0x0F))
    host.run_for(2.0)
    pos = struct.unpack("<i", sdo.upload(0x6064, 0))[0]
    sw = struct.unpack("<H", sdo.upload(0x6041, 0))[0]
    return pos, sw


@pytest.fixture
def network(tmp_path: Path) -> Iterator[canopen.Network]:
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="esd_can_ethercat", channel=f"rig:{rig}", slave=0, bitrate=500_000, cycle_us=1000)
    try:
        yield net
    finally:
        net.disconnect()


def test_canopen_sdo_upload_through_the_plugin(network: canopen.Network) -> None:
    """Issue 12: canopen.Network().connect(interface="esd_can_ethercat", channel="rig:PATH") reads
    0x1008 'Manufacturer device name' of the drive behind the gateway (SDO upload, segmented:
    several request/answer pairs through the Tx/Rx batches of 5.1.5.1/5.1.5.3)."""
    node = network.add_node(NODE, canopen.ObjectDictionary())
    assert node.sdo.upload(0x1008, 0).startswith(b"IDX")
    assert node.sdo.upload(0x1018, 4) == _u32(0x1002)


def test_canopen_profile_position_move_through_the_plugin(network: canopen.Network) -> None:
    """Issue 12 'reading and moving the same drive': CiA 402 enable and a profile position move to
    20000 inc by SDO through the gateway; the drive reaches it (statusword bit 10 'target reached')."""
    node = network.add_node(NODE, canopen.ObjectDictionary())
    bus = network.bus
    assert isinstance(bus, can.BusABC)
    host = bus.host   # type: ignore[attr-defined]
    pos, sw = move_pp(node, host, 20_000)
    assert abs(pos - 20_000) <= 10
    assert sw & 0x400


class TwoGateways:
    """Two esd gateways on one segment, each on its own CAN bus with its own drive (node 2 / 3)."""

    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.buses = [VirtualBus(self.clock, f"can{i}", bitrate=500_000) for i in range(2)]
        self.gws: list[EsdGateway] = [create_esd_gateway(self.clock, b, f"esd{i}", serial=0x10 + i)
                                      for i, b in enumerate(self.buses)]
        self.drives = [Drive(self.clock, b, 2 + i, 0x1002 + i) for i, b in enumerate(self.buses)]
        for d in self.drives:
            d.start()
        backend = InProcessBackend(Master(self.clock, Segment([g.slave for g in self.gws])))
        self.host = EthercatHost(backend, cycle_us=1000)
        self.host.add_esd(0, 500_000, name="left")
        self.host.add_esd(1, 500_000, name="right")
        self.host.start()

    def close(self) -> None:
        self.host.close()
        for g in self.gws:
            g.stop()


@pytest.fixture
def two() -> Iterator[TwoGateways]:
    t = TwoGateways()
    try:
        yield t
    finally:
        t.close()


def test_several_channels_of_one_host_at_once(two: TwoGateways) -> None:
    """Issue 12: one EthercatHost hands out a BusABC per gateway channel, several at once; each
    canopen Network reaches only the drive behind its own gateway."""
    nets = []
    for name in ("left", "right"):
        net = canopen.Network(two.host.bus(name))
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
        nets.append(net)
    try:
        left = nets[0].add_node(2, canopen.ObjectDictionary())
        right = nets[1].add_node(3, canopen.ObjectDictionary())
        assert left.sdo.upload(0x1018, 4) == _u32(0x1002)
        assert right.sdo.upload(0x1018, 4) == _u32(0x1003)
        nets[1].add_node(2, canopen.ObjectDictionary())
        with pytest.raises(canopen.SdoCommunicationError):   # no node 2 behind the right gateway
            nets[1].nodes[2].sdo.upload(0x1018, 4)
    finally:
        for net in nets:
            net.disconnect()


def test_received_frames_carry_the_host_time(two: TwoGateways) -> None:
    """Frames come out of recv() with Message.timestamp = the time of the cycle that brought them
    (the esd Rx PDO has no time stamp, 5.1.5.1), channel = the gateway channel, is_rx."""
    bus = two.host.bus("left")
    try:
        t0 = two.host.clock.now()
        bus.send(can.Message(arbitration_id=0x602, data=[0x40, 0x18, 0x10, 4, 0, 0, 0, 0], is_extended_id=False))
        msg = bus.recv(1.0)
        while msg is not None and msg.arbitration_id == 0x702:   # the drive's boot-up came first
            msg = bus.recv(1.0)
        while msg is not None and msg.arbitration_id != 0x582:   # boot-up and error frames first
            msg = bus.recv(1.0)
        assert msg is not None and msg.channel == "left" and msg.is_rx
        assert t0 < msg.timestamp <= two.host.clock.now()
    finally:
        bus.shutdown()


def test_bus_off_surfaces_as_error_frame_and_refused_send(two: TwoGateways) -> None:
    """Bus-off of the gateway's controller (0xF108:01 in the 0x1A85 status PDO, 5.1.5.8) comes out
    of recv() as a SocketCAN-style error frame (CAN_ERR_BUSOFF); while it lasts the bus state is
    ERROR and send() raises can.CanOperationError; after recovery the channel works again."""
    bus = two.host.bus("left")
    try:
        ctrl = two.gws[0].controller
        assert ctrl is not None
        two.buses[0].force_bus_off(ctrl)
        two.host.run_for(0.01)
        msg = bus.recv(1.0)
        while msg is not None and not msg.is_error_frame:   # the drive's boot-up came first
            msg = bus.recv(1.0)
        assert msg is not None and msg.is_error_frame and msg.arbitration_id & 0x40
        two.host.run_for(0.1)            # the controller recovers (128 x 11 recessive bits)
        assert bus.state is can.BusState.ACTIVE
        bus.send(can.Message(arbitration_id=0x602, data=[0x40, 0, 0x10, 0, 0, 0, 0, 0], is_extended_id=False))
        msg = bus.recv(1.0)
        while msg is not None and msg.arbitration_id != 0x582:   # boot-up and error frames first
            msg = bus.recv(1.0)
        assert msg is not None
    finally:
        bus.shutdown()


def test_shutdown_leaves_the_gateways_in_preop(two: TwoGateways) -> None:
    """Issue 12 'shutdown() leaves the slaves in a safe state': after close() every gateway is in
    PREOP (no process data taken, the queues reset on the next PREOP -> SAFEOP, 5.1.5.1) and a
    bus of the host refuses send()."""
    bus = two.host.bus("right")
    assert all(g.slave.esc.al_state == AlState.OP for g in two.gws)
    two.host.close()
    assert all(g.slave.esc.al_state == AlState.PREOP for g in two.gws)
    with pytest.raises(can.CanOperationError):
        bus.send(can.Message(arbitration_id=0x603, data=[0x40, 0, 0x10, 0, 0, 0, 0, 0], is_extended_id=False))
    assert bus.recv(0) is None
    bus.shutdown()
