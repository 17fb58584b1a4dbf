"""python-can over the EtherCAT gateways (issue 12 'python-can on top'): canopen's Network through
``can.Bus(interface="esd_can_ethercat")`` and ``can.Bus(interface="ecanlite")`` reads and moves the
same CiA 402 drive behind both gateways, in process on a simulated clock (esd manual 5.1.5: the
counter handshake; ECAN-Lite manual 15.1: the MCAN Port over the frame stream)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.canhost import EthercatHost
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master

RIG = """
[[bus]]
name = "can0"
bitrate = 500000

[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"

[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can0"]

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
"""
NODE = 2
#: The same application on either gateway: only the interface name and its arguments change.
INTERFACES = {"esd_can_ethercat": {"slave": 0, "bitrate": 500_000},
              "ecanlite": {"slave": 1, "can_channel": 0, "bitrate": 500_000, "pdo_n": 3}}


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


@pytest.fixture(params=sorted(INTERFACES))
def network(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[canopen.Network]:
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface=request.param, channel=f"rig:{rig}", cycle_us=1000, **INTERFACES[request.param])
    try:
        yield net
    finally:
        net.disconnect()


def test_canopen_sdo_upload_through_the_plugin(network: canopen.Network) -> None:
    """Issue 12: canopen.Network().connect(interface="esd_can_ethercat" or "ecanlite",
    channel="rig:PATH") reads 0x1008 'Manufacturer device name' of the drive behind the gateway
    (SDO upload, segmented: several request/answer pairs through the process data)."""
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
    """One segment: esd gateways at 0 and 1 (buses can0, can1), an ECAN-Lite at 2 with its four
    MCAN channels on can2..can5; one drive on every bus, node 2 + bus number."""

    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.buses = [VirtualBus(self.clock, f"can{i}", bitrate=500_000) for i in range(6)]
        self.gws: list[EsdGateway] = [create_esd_gateway(self.clock, b, f"esd{i}", serial=0x10 + i)
                                      for i, b in enumerate(self.buses[:2])]
        self.ecan = EcanLiteDevice(self.clock, [b.attach(f"ecan.mcan{i}") for i, b in enumerate(self.buses[2:])])
        self.drives = [Drive(self.clock, b, 2 + i, 0x1002 + i) for i, b in enumerate(self.buses)]
        for d in self.drives:
            d.start()
        segment = Segment([g.slave for g in self.gws] + [self.ecan.slave])
        backend = InProcessBackend(Master(self.clock, segment))
        self.host = EthercatHost(backend, cycle_us=1000)
        self.host.add_esd(0, 500_000, name="left")
        self.host.add_esd(1, 500_000, name="right")
        for ch in range(4):
            self.host.add_ecanlite(2, ch, 500_000, name=f"mcan{ch}")
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
    """Issue 12: one EthercatHost hands out a BusABC per gateway channel, several at once (two esd
    gateways and all four ECAN-Lite channels of one segment); each canopen Network reaches only the
    drive behind its own channel."""
    nets = []
    for name in ("left", "right", "mcan0", "mcan1", "mcan2", "mcan3"):
        net = canopen.Network(two.host.bus(name))
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
        nets.append(net)
    try:
        for i, net in enumerate(nets):
            node = net.add_node(2 + i, canopen.ObjectDictionary())
            assert node.sdo.upload(0x1018, 4) == _u32(0x1002 + i)
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
    PREOP (no process data taken; esd queues reset on the next PREOP -> SAFEOP, 5.1.5.1; ECAN-Lite
    leaves OP, 14.2) and a bus of the host refuses send()."""
    bus = two.host.bus("right")
    slaves = [g.slave for g in two.gws] + [two.ecan.slave]
    assert all(s.esc.al_state == AlState.OP for s in slaves)
    two.host.close()
    assert all(s.esc.al_state == AlState.PREOP for s in slaves)
    with pytest.raises(can.CanOperationError):
        bus.send(can.Message(arbitration_id=0x603, data=[0x40, 0, 0x10, 0, 0, 0, 0, 0], is_extended_id=False))
    assert bus.recv(0) is None
    bus.shutdown()


def _first_error(bus: can.BusABC) -> can.Message | None:
    msg = bus.recv(1.0)
    while msg is not None and not msg.is_error_frame:   # boot-up messages first
        msg = bus.recv(1.0)
    return msg


def test_ecanlite_bus_off_is_an_error_frame(two: TwoGateways) -> None:
    """ECAN-Lite chapter 7: status word bits 0..2 = 3 (BUSOFF) of an MCAN channel comes out of that
    channel's recv() as a CAN_ERR_BUSOFF error frame; the other channels see none."""
    bus, other = two.host.bus("mcan1"), two.host.bus("mcan2")
    try:
        ctrl = next(c for c in two.buses[3].controllers if c.name == "ecan.mcan1")
        two.buses[3].force_bus_off(ctrl)
        two.host.run_for(0.005)
        msg = _first_error(bus)
        assert msg is not None and msg.arbitration_id & 0x40 and msg.channel == "mcan1"
        while (m := other.recv(0)) is not None:
            assert not m.is_error_frame
    finally:
        bus.shutdown()
        other.shutdown()


def test_ecanlite_parse_error_is_an_error_frame(two: TwoGateways) -> None:
    """A TxPDO the host rejects (CRC16 wrong, chapter 6; the package's parse_diag) is counted and
    comes out of recv() as an error frame (CAN_ERR_CRTL, data[1] = 0) on the slave's channels."""
    bus = two.host.bus("mcan0")
    try:
        port = two.host.port
        assert port is not None
        with two.clock.lock:
            image = bytearray(two.host.backend.inputs(2))
            seq = (int.from_bytes(image[2:4], "little") + 0x100) & 0xFFFF
            image[2:6] = seq.to_bytes(2, "little") * 2          # a new sequence, committed (seq_begin = seq_end)
            image[8] ^= 0xFF                                     # payload_crc16 no longer fits
            port.parse(0, bytes(image))
        two.host.run_for(0.002)
        msg = _first_error(bus)
        assert msg is not None and msg.arbitration_id == 0x04 and msg.data[1] == 0
        assert two.host.parse_errors >= 1
    finally:
        bus.shutdown()


def test_a_gateway_fallen_to_safeop_is_brought_back(two: TwoGateways) -> None:
    """ETG.1000.6 SM watchdog: a gateway that fell to SAFEOP (here: requested) is found by the
    host's look at the AL states (every 0.1 s, at once after 10 cycles with a wrong working
    counter) and brought back to OP; the channel carries frames again (the esd counters survive
    SAFEOP, 5.1.5.1)."""
    bus = two.host.bus("left")
    try:
        with two.clock.lock:
            two.host.backend.request_state(AlState.SAFEOP, 0)
        two.host.run_for(0.25)
        assert two.host.recoveries == 1
        assert two.gws[0].slave.esc.al_state == AlState.OP
        bus.send(can.Message(arbitration_id=0x602, data=[0x40, 0x18, 0x10, 4, 0, 0, 0, 0], is_extended_id=False))
        msg = bus.recv(1.0)
        while msg is not None and msg.arbitration_id != 0x582:
            msg = bus.recv(1.0)
        assert msg is not None and bytes(msg.data[4:]) == _u32(0x1002)
    finally:
        bus.shutdown()
