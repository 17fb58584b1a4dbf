"""CAN FD through an ECAN-Lite channel opened with fd=True (issue 12 'data_bitrate=None, fd=False'
arguments; ECAN-Lite manual 13.4 FD channel setup, chapter 8 FD packets)."""

from __future__ import annotations

import can
import pytest

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.canhost import EthercatHost
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master


def test_fd_frames_both_ways() -> None:
    """A 64-byte FD frame with BRS sent through the python-can bus reaches the CAN FD bus as it is;
    the peer's FD answer comes out of recv() as an FD message; the bus reports CAN FD. A classic
    channel refuses an FD frame with can.CanOperationError."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=1_000_000, data_bitrate=5_000_000)
    classic = VirtualBus(clock, "can1", bitrate=1_000_000)
    ecan = EcanLiteDevice(clock, [bus.attach("ecan.mcan0", fd=True), classic.attach("ecan.mcan1")])
    heard: list[CanFrame] = []
    peer = bus.attach("peer", fd=True)

    def answer(frame: CanFrame, t: float) -> None:
        heard.append(frame)
        peer.send(CanFrame(frame.can_id + 1, frame.data[::-1], fd=True, brs=True))

    peer.on_frame = answer
    classic.attach("acker")
    host = EthercatHost(InProcessBackend(Master(clock, Segment([ecan.slave]))), cycle_us=1000)
    host.add_ecanlite(0, 0, 1_000_000, 5_000_000, fd=True, name="fd")
    host.add_ecanlite(0, 1, 1_000_000, name="classic")
    host.start()
    try:
        fd_bus, classic_bus = host.bus("fd"), host.bus("classic")
        assert fd_bus.protocol is can.CanProtocol.CAN_FD
        data = bytes(range(64))
        fd_bus.send(can.Message(arbitration_id=0x123, data=data, is_fd=True, bitrate_switch=True,
                                is_extended_id=False))
        assert heard and heard[0].fd and heard[0].brs and heard[0].data == data
        msg = fd_bus.recv(1.0)
        assert msg is not None and msg.is_fd and msg.arbitration_id == 0x124 and bytes(msg.data) == data[::-1]
        with pytest.raises(can.CanOperationError):
            classic_bus.send(can.Message(arbitration_id=0x200, data=data, is_fd=True, is_extended_id=False))
        fd_bus.shutdown()
        classic_bus.shutdown()
    finally:
        host.close()
