"""The IDX device on a simulated clock: USB channel + its own drive + gateway to other drives.

IDX guide 2.2.6 (frame timeout object), chapter 5 (gateway), 3.3.3.5 (NMT), chapter 6 (codes).
"""

from __future__ import annotations

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.maxon_idx.codec import FrameDecoder, FrameReceived, encode_frame
from gatewaylab.devices.maxon_idx.commands import (
    ReadObject,
    ReadObjectReply,
    Reply,
    Request,
    SendNmtService,
    StatusReply,
    WriteObject,
    decode_reply,
)
from gatewaylab.devices.maxon_idx.device import IdxDevice


class Host:
    """One USB channel of the device, replies decoded in arrival order."""

    def __init__(self, device: IdxDevice, clock: SimulatedClock) -> None:
        self.replies: list[object] = []
        self.decoder = FrameDecoder(clock, self._on_event, timeout=None)
        self.channel = device.open_channel(self.decoder.feed)
        self.opcodes: list[int] = []

    def _on_event(self, event: object) -> None:
        assert isinstance(event, FrameReceived)
        self.replies.append(decode_reply(self.opcodes.pop(0), event.frame))

    def send(self, request: Request) -> None:
        self.opcodes.append(request.opcode)
        self.channel.receive(encode_frame(request.to_frame()))


class World:
    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.bus = VirtualBus(self.clock, "can0", bitrate=1_000_000)
        self.frames: list[CanFrame] = []
        self.bus.add_monitor(lambda f, t: self.frames.append(f))
        self.idx = IdxDevice(self.clock, self.bus, 1, 0x2001, "idx1")
        self.drive = Drive(self.clock, self.bus, 2, 0x1002, "drive2")
        self.idx.start()
        self.drive.start()
        self.clock.advance(0.05)
        self.host = Host(self.idx, self.clock)

    def ask(self, request: Request, dt: float = 0.01) -> Reply:
        self.host.send(request)
        self.clock.advance(dt)
        reply = self.host.replies.pop(0)
        assert isinstance(reply, StatusReply | ReadObjectReply)
        return reply


def test_frame_timeout_follows_object_0x2006() -> None:
    """2.2.6: 0x2006 USB frame timeout, default 500 ms, may be changed by writing the object."""
    w = World()
    wire = encode_frame(ReadObject(0, 0x1018, 4).to_frame())
    w.host.opcodes.append(0x60)
    w.host.channel.receive(wire[:5])
    w.clock.advance(0.3)                      # within the default 500 ms
    w.host.channel.receive(wire[5:])
    assert w.host.replies == [ReadObjectReply(0, (0x2001).to_bytes(4, "little"))]
    w.host.replies.clear()
    assert w.ask(WriteObject(0, 0x2006, 0, (100).to_bytes(4, "little"))) == StatusReply(0)
    w.host.channel.receive(wire[:5])
    w.clock.advance(0.15)                     # beyond the new 100 ms: the partial frame is dropped
    w.host.channel.receive(wire[5:])
    w.clock.advance(0.01)
    assert w.host.replies == []
    assert w.host.channel.decoder.stats.timeouts == 1
    w.host.opcodes.clear()
    assert w.ask(ReadObject(1, 0x2006, 0)) == ReadObjectReply(0, (100).to_bytes(4, "little"))


def test_gateway_write_is_expedited_without_size() -> None:
    """Chapter 5 + CiA 301: WriteObject's 4 bytes go out as an expedited download with the size
    not indicated (cs 0x22), so a 2-byte object on the drive takes its own size."""
    w = World()
    assert w.ask(WriteObject(2, 0x2006, 0, (250).to_bytes(4, "little"))) == StatusReply(0)
    request = next(f for f in w.frames if f.can_id == 0x602)
    assert request.data == bytes([0x22, 0x06, 0x20, 0x00, 250, 0, 0, 0])
    assert w.drive.node.get(0x2006, 0) == 250
    assert w.ask(ReadObject(2, 0x2006, 0)) == ReadObjectReply(0, bytes([250, 0, 0, 0]))


def test_gateway_abort_passes_through_and_timeout_at_sdo_timeout() -> None:
    """Chapter 6: the node's abort code is returned; a silent node -> 0x05040000 after the SDO timeout."""
    w = World()
    assert w.ask(WriteObject(2, 0x1018, 1, bytes(4))) == StatusReply(0x06010002)
    w.host.send(ReadObject(9, 0x1000, 0))
    w.clock.advance(0.45)
    assert w.host.replies == []
    w.clock.advance(0.1)
    assert w.host.replies == [ReadObjectReply(0x05040000)]
    w.host.replies.clear()
    w.host.send(WriteObject(9, 0x1000, 0, bytes(4)))
    w.clock.advance(0.6)
    assert w.host.replies == [StatusReply(0x05040000)]
    assert any(f.can_id == 0x609 and f.data[0] == 0x80 for f in w.frames)   # abort sent to the node


def test_nmt_broadcast_reaches_drives_and_the_idx_itself() -> None:
    """Table 3-12: node id 0 addresses all NMT slaves -- the drive on the bus and the IDX."""
    w = World()
    assert w.ask(SendNmtService(0, 1)) == StatusReply(0)
    assert CanFrame(0, bytes([1, 0])) in w.frames
    assert w.drive.node.nmt_state is NmtState.OPERATIONAL
    assert w.idx.node.nmt_state is NmtState.OPERATIONAL
    assert w.ask(SendNmtService(2, 2)) == StatusReply(0)
    assert w.drive.node.nmt_state is NmtState.STOPPED
    assert w.idx.node.nmt_state is NmtState.OPERATIONAL


def test_two_hosts_share_the_gateway() -> None:
    """2.2.1: each channel gets exactly its own answers even when both use the gateway at once."""
    w = World()
    other = Host(w.idx, w.clock)
    w.host.send(ReadObject(2, 0x1018, 4))
    other.send(ReadObject(2, 0x1018, 2))
    w.host.send(ReadObject(0, 0x1018, 4))
    w.clock.advance(0.02)
    assert w.host.replies == [ReadObjectReply(0, (0x1002).to_bytes(4, "little")),
                              ReadObjectReply(0, (0x2001).to_bytes(4, "little"))]
    product = w.drive.node.get(0x1018, 2)
    assert other.replies == [ReadObjectReply(0, int(product).to_bytes(4, "little"))]


def test_gateway_read_object_of_a_string_is_refused_after_one_sdo_exchange() -> None:
    """2.1.1.1 (ReadObject: "an object with up to 4 bytes") through the gateway of chapter 5: the
    drive answers the initiate upload of its 0x1008 name segmented; the IDX aborts with 0x06070010
    on the bus, answers that code, and the drive serves the next request normally."""
    w = World()
    assert w.ask(ReadObject(2, 0x1008, 0)) == ReadObjectReply(0x06070010)
    to_drive = [f for f in w.frames if f.can_id == 0x602]
    assert [f.data[0] for f in to_drive] == [0x40, 0x80]
    assert to_drive[1].data[4:] == (0x06070010).to_bytes(4, "little")
    assert w.ask(ReadObject(2, 0x1018, 4)) == ReadObjectReply(0, (0x1002).to_bytes(4, "little"))
