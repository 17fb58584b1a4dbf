"""python-can over the EtherCAT gateways, send timeouts and receive timestamps (issue 12 'python-can
on top'), in process on a simulated clock: ``send(msg, timeout)`` waits for room in the gateway's
Tx path as python-can defines it (esd manual 5.1.5.3 / 5.1.5.5: the local Tx queue 0x8000:24 and
one Tx batch 0x8000:22; ECAN-Lite manual chapter 12: one RxPDO frame area), and ``recv()`` gives
the ECAN-Lite's bus receive instant (8.4 delta16 timestamps, profile 1 of chapter 9)."""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest

from gatewaylab.bus import CanFrame
from gatewaylab.bus.bus import VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.canhost import EthercatHost
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master

EPOCH = 1_700_000_000.0
#: esd defaults (5.1.5.5): local Tx queue 1000 (0x8000:24), 16 messages per Tx batch (0x8000:22)
ESD_TX_PATH = 1000 + 16
#: ECAN-Lite N = 3: 384 B RxPDO, 360 B frame area; a classic 8-byte frame is 12 B (8.3)
ECAN_IMAGE_FRAMES = 360 // 12


class Line:
    """An esd gateway (position 0) alone on ``esd_bus`` (nobody acknowledges: its frames stay in
    its Tx queue) and an ECAN-Lite (position 1) with MCAN 0 on ``ecan_bus`` next to a peer."""

    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.esd_bus = VirtualBus(self.clock, "esd", bitrate=500_000)
        self.ecan_bus = VirtualBus(self.clock, "ecan", bitrate=500_000)
        self.gw: EsdGateway = create_esd_gateway(self.clock, self.esd_bus, "esd1")
        self.ecan = EcanLiteDevice(self.clock, [self.ecan_bus.attach("ecan.mcan0")])
        self.peer_rx: list[tuple[float, CanFrame]] = []
        self.peer = self.ecan_bus.attach("peer", on_frame=lambda f, t: self.peer_rx.append((t, f)))
        backend = InProcessBackend(Master(self.clock, Segment([self.gw.slave, self.ecan.slave])))
        self.host = EthercatHost(backend, cycle_us=1000, wall_epoch=EPOCH)
        self.host.add_esd(0, 500_000, name="esd")
        self.host.add_ecanlite(1, 0, 500_000, name="mcan0")
        self.host.start()

    def close(self) -> None:
        self.host.close()
        self.gw.stop()


@pytest.fixture
def line() -> Iterator[Line]:
    t = Line()
    try:
        yield t
    finally:
        t.close()


def _msg(i: int) -> can.Message:
    return can.Message(arbitration_id=0x100 + i % 0x100, data=i.to_bytes(8, "little"), is_extended_id=False)


def test_send_timeout_on_a_full_esd_tx_queue(line: Line) -> None:
    """5.1.5.3/5.1.5.5: with nobody acknowledging on the bus, the gateway keeps its frames; once its
    local Tx queue (0x8000:24) and a Tx batch (0x8000:22) are taken, send(timeout=0) refuses at
    once and send(timeout=T) after T of waiting (can.CanOperationError); when a node acknowledges
    again the queue drains and send(timeout=None) goes through."""
    bus = line.host.bus("esd")
    try:
        t0 = line.clock.now()
        for i in range(ESD_TX_PATH):
            bus.send(_msg(i), timeout=0)
        assert line.clock.now() == t0             # non-blocking: no simulated time passed
        with pytest.raises(can.CanOperationError, match="no room"):
            bus.send(_msg(0), timeout=0)
        with pytest.raises(can.CanOperationError, match=r"within 0\.005 s"):
            bus.send(_msg(0), timeout=0.005)
        assert line.clock.now() - t0 == pytest.approx(0.005)
        hs = line.host.channels["esd"].esd.handshake    # type: ignore[attr-defined]
        assert hs.pending + hs.in_flight == ESD_TX_PATH and hs.in_flight > 0   # batches reached the gateway
        heard: list[CanFrame] = []
        line.esd_bus.attach("acker", on_frame=lambda f, _t: heard.append(f))
        bus.send(_msg(ESD_TX_PATH), timeout=None)
        assert heard and heard[0].data == (0).to_bytes(8, "little")           # in order, from the first
    finally:
        bus.shutdown()


def test_send_timeout_on_a_full_ecanlite_image(line: Line) -> None:
    """Chapter 12: one RxPDO frame area (N = 3: 360 B, 30 classic frames of 12 B) is the ECAN-Lite
    Tx path the host fills; send(timeout=0) refuses the 31st frame, send(timeout=T) waits for the
    next cycle to take the image and goes through; every frame reaches the bus in order."""
    bus = line.host.bus("mcan0")
    try:
        t0 = line.clock.now()
        for i in range(ECAN_IMAGE_FRAMES):
            bus.send(_msg(i), timeout=0)
        with pytest.raises(can.CanOperationError, match="no room"):
            bus.send(_msg(ECAN_IMAGE_FRAMES), timeout=0)
        assert line.clock.now() == t0
        bus.send(_msg(ECAN_IMAGE_FRAMES), timeout=0.01)
        waited = line.clock.now() - t0
        assert 0 < waited < 0.01 + 1e-9
        line.host.run_for(0.05)
        got = [f.data for _t, f in line.peer_rx]
        assert got == [i.to_bytes(8, "little") for i in range(ECAN_IMAGE_FRAMES + 1)]
    finally:
        bus.shutdown()


def test_ecanlite_recv_timestamp_is_the_bus_receive_instant(line: Line) -> None:
    """8.4: the TxPDO timestamp 'describes the time when the slave receives the CAN frame'; with
    profile 1 (delta16, chapter 9) recv() gives Message.timestamp = wall_epoch + the instant the
    frame ended on the bus (the gateway's receive), to the 1 us tick, not the cycle's time."""
    bus = line.host.bus("mcan0")
    try:
        ends: list[float] = []
        line.ecan_bus.attach("witness", on_frame=lambda _f, t: ends.append(t))
        line.host.run_for(0.0031)
        for k, phase in enumerate((0.0001, 0.00042, 0.00087)):
            line.clock.call_at(line.clock.now() + phase, line.peer.send, CanFrame(0x300 + k, bytes([k] * 8)))
            line.host.run_for(0.001)
        line.host.run_for(0.005)
        msgs = []
        while (m := bus.recv(0)) is not None:
            msgs.append(m)
        assert [m.arbitration_id for m in msgs] == [0x300, 0x301, 0x302]
        assert len(ends) == 3
        for m, end in zip(msgs, ends, strict=True):
            assert m.timestamp == pytest.approx(EPOCH + end, abs=1e-6)
            assert m.channel == "mcan0" and m.is_rx
        cycle_times = {round(m.timestamp - EPOCH, 3) for m in msgs}
        assert len(cycle_times) == 3       # three instants inside three cycles, not cycle boundaries
    finally:
        bus.shutdown()


def test_esd_recv_timestamp_is_the_cycle_time(line: Line) -> None:
    """5.1.5.1: the esd Rx PDO carries no time stamp; Message.timestamp is wall_epoch + the time
    of the cycle whose inputs brought the frame (a multiple of the cycle on this clock)."""
    bus = line.host.bus("esd")
    try:
        sender = line.esd_bus.attach("sender")
        line.host.run_for(0.0023)
        sender.send(CanFrame(0x123, b"\x01\x02"))
        line.host.run_for(0.01)
        m = bus.recv(0)
        while m is not None and m.is_error_frame:
            m = bus.recv(0)
        assert m is not None and m.arbitration_id == 0x123
        t = m.timestamp - EPOCH
        assert t > 0.0023 and abs(t - round(t, 3)) < 1e-6
    finally:
        bus.shutdown()


def test_ecanlite_bus_hands_over_a_full_bus_burst(line: Line) -> None:
    """13.2.2: the device's default data path drains at most 2 frames per cycle (0x802x:05) into a
    16-frame RX cache (:07 = 2), so a busy bus overflows it; the python-can interface configures the
    channel to drain the whole cache (budget max 8, policy 2 'performance', depth 32): 60 frames sent
    back to back on a 500 kbit/s bus (about 4 per 1 ms cycle) all come out of recv(), in order."""
    bus = line.host.bus("mcan0")
    try:
        for i in range(60):
            line.peer.send(CanFrame(0x300 + i, i.to_bytes(8, "little")))
        line.host.run_for(0.05)
        got = []
        while (m := bus.recv(0)) is not None:
            got.append(m)
        assert [m.arbitration_id for m in got if not m.is_error_frame] == [0x300 + i for i in range(60)]
        assert not any(m.is_error_frame for m in got)
    finally:
        bus.shutdown()
