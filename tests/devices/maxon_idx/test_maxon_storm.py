"""Storms of random and corrupted USB frames against the IDX (issue 15: 'The same for the IDX: 2,903
random and corrupted USB frames in 30 s left it answering correctly (keep it so, in a test)').

IDX guide 2.2.1-2.2.6: DLE/STX framing, Len in words, CRC-CCITT, frame timeout; chapter 6 error codes.
"""

from __future__ import annotations

import random
import socket
import threading

from maxon_helpers import IdxRig

from gatewaylab.bus import VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.maxon_idx.codec import CrcFailed, Frame, FrameDecoder, FrameReceived, encode_frame
from gatewaylab.devices.maxon_idx.commands import (
    InitiateSegmentedRead,
    OpCode,
    ReadObject,
    ReadObjectReply,
    SegmentRead,
    decode_reply,
)
from gatewaylab.devices.maxon_idx.device import IdxDevice
from gatewaylab.devices.maxon_idx.errors import idx_codes
from gatewaylab.hosts.maxon_idx.client import IdxClient

#: Requests that change the device or the bus (a storm of valid ones would legitimately change what a
#: later read returns) or keep it busy for up to 65 s (ReadLSS timeout, 2.1.3.2): the storm sends them
#: only corrupted (bad CRC).
CHANGING = {OpCode.WRITE_OBJECT, OpCode.INITIATE_SEGMENTED_WRITE, OpCode.SEGMENT_WRITE,
            OpCode.SEND_NMT_SERVICE, OpCode.SEND_LSS, OpCode.READ_LSS}
SPEC_CODES = {int(c) for c in idx_codes()}
CHECKS = ((1, 0x1018, 4, 0x2001), (0, 0x1018, 4, 0x2001), (2, 0x1018, 4, 0x1002))


def _valid_request(rng: random.Random) -> bytes:
    node = rng.choice((0, 1, 2, 3, rng.randrange(256)))
    index, sub = rng.choice(((0x1018, rng.randrange(6)), (0x1008, 0), (0x2006, 0), (rng.randrange(0x10000),
                                                                                      rng.randrange(256))))
    request = rng.choice((ReadObject(node, index, sub), InitiateSegmentedRead(node, index, sub),
                          SegmentRead(rng.random() < 0.5)))
    return encode_frame(request.to_frame())


def usb_storm_frame(rng: random.Random) -> bytes:
    """Random bytes, corrupted requests (bit flips, cuts, lying Len, stray DLE), and CRC-valid frames
    of any opcode and length except the state-changing commands."""
    kind = rng.random()
    if kind < 0.15:
        return rng.randbytes(rng.randrange(1, 60))
    if kind < 0.35:  # CRC-valid frame, random opcode and data
        opcode = rng.randrange(256)
        while opcode in CHANGING:
            opcode = rng.randrange(256)
        return encode_frame(Frame(opcode, rng.randbytes(2 * rng.choice((0, 1, 2, 3, 4, rng.randrange(144))))))
    raw = bytearray(_valid_request(rng) if rng.random() < 0.6 else encode_frame(Frame(
        rng.choice(sorted(CHANGING)), rng.randbytes(2 * rng.randrange(1, 8)))))
    if raw[2] in CHANGING:  # never valid: flip a bit of the CRC's last byte
        raw[-1] ^= 1 << rng.randrange(8)
        return bytes(raw)
    how = rng.randrange(5)
    if how == 0:  # bit flips
        for _ in range(rng.randint(1, 3)):
            raw[rng.randrange(2, len(raw))] ^= 1 << rng.randrange(8)
    elif how == 1:
        raw = raw[:rng.randrange(2, len(raw))]  # cut short
    elif how == 2:
        raw[3] = rng.randrange(256)  # Len lies
    elif how == 3:
        raw.insert(rng.randrange(2, len(raw)), 0x90)  # a stray DLE
    else:
        raw += rng.randbytes(rng.randrange(1, 10))  # trailing garbage
    return bytes(raw)


class Host:
    """A USB channel of the device; every reply byte decoded (CRC checked) in arrival order."""

    def __init__(self, device: IdxDevice, clock: SimulatedClock) -> None:
        self.events: list[object] = []
        self.decoder = FrameDecoder(clock, self.events.append, timeout=None)
        self.channel = device.open_channel(self.decoder.feed)


def test_usb_storm_leaves_idx_answering_correctly() -> None:
    """Thousands of random and corrupted frames: every byte the IDX sends is a CRC-valid OpCode 0x00 reply
    with an error DWORD of chapter 6 (2.2.1 'All commands send an answer'); after each burst and the
    frame timeout (2.2.6, 500 ms) local reads and gateway reads (chapter 5) answer the right values."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=1_000_000)
    idx = IdxDevice(clock, bus, 1, 0x2001, "idx1")
    drive = Drive(clock, bus, 2, 0x1002, "drive2")
    idx.start()
    drive.start()
    clock.advance(0.05)
    host = Host(idx, clock)
    rng = random.Random(2903)
    sent = 0
    for _burst in range(15):
        for _ in range(200):
            host.channel.receive(usb_storm_frame(rng))
            sent += 1
            clock.advance(rng.choice((0.0, 0.0001, 0.002)))
        # The storm queued requests (a host ignoring 2.2.8 D); gateway reads to absent nodes end at the
        # SDO timeout one by one: wait until the channel is quiet (and the 2.2.6 frame timeout ran).
        for _ in range(200):
            before = len(host.events)
            clock.advance(1.0)
            if len(host.events) == before:
                break
        for e in host.events:
            assert isinstance(e, FrameReceived), e
            assert e.frame.opcode == 0x00 and e.frame.length >= 2
            assert int.from_bytes(e.frame.data[:4], "little") in SPEC_CODES | {0}
        host.events.clear()
        for node, index, sub, value in CHECKS:
            host.channel.receive(encode_frame(ReadObject(node, index, sub).to_frame()))
            clock.advance(0.05)
            assert len(host.events) == 1
            event = host.events.pop()
            assert isinstance(event, FrameReceived)
            assert decode_reply(OpCode.READ_OBJECT, event.frame) == ReadObjectReply(0, value.to_bytes(4, "little"))
    assert sent == 3000
    assert host.channel.decoder.stats.crc_errors > 100


def _tcp_address(rig: IdxRig) -> tuple[str, int]:
    text = str(rig.info["usb"]["idx1"]["tcp"])
    return "127.0.0.1", int(text.rsplit(":", 1)[1].strip("/"))


def test_usb_storm_over_tcp_while_another_client_reads() -> None:
    """The TCP transport (2.2 data link over a socket): one connection floods random and corrupted
    frames while a second one keeps reading through IdxClient without an error; afterwards the
    flooding connection's own channel answers correctly again (after the 2.2.6 frame timeout)."""
    rig = IdxRig([(2, 0x1002)])
    try:
        address = _tcp_address(rig)
        url = f"socket://{address[0]}:{address[1]}"
        rng = random.Random(15)
        frames = [usb_storm_frame(rng) for _ in range(3000)]
        done = threading.Event()
        received = bytearray()

        def flood() -> None:
            with socket.create_connection(address, timeout=10) as s:
                for f in frames:
                    s.sendall(f)
                    s.setblocking(False)
                    try:
                        while chunk := s.recv(65536):
                            received.extend(chunk)
                    except BlockingIOError:
                        pass
                    s.setblocking(True)
            done.set()

        flooder = threading.Thread(target=flood, daemon=True)
        flooder.start()
        reads = 0
        with IdxClient(url, timeout=5.0) as c:
            while not done.is_set() or reads < 10:
                for node, index, sub, value in CHECKS:
                    assert c.read(node, index, sub) == value
                    reads += 1
        flooder.join(30)
        assert done.is_set()
        events: list[object] = []
        decoder = FrameDecoder(rig.rig.clock, events.append, timeout=None)
        decoder.feed(bytes(received))
        assert events and not any(isinstance(e, CrcFailed) for e in events)
        with IdxClient(url, timeout=5.0) as c:
            for node, index, sub, value in CHECKS:
                assert c.read(node, index, sub) == value
    finally:
        rig.close()
