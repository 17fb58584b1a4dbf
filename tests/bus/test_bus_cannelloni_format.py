"""The cannelloni UDP format (mguentner/cannelloni doc/udp_format.md 'cannelloni UDP/SCTP Format version
2', parser.cpp parseFrames/encodeFrame/buildPacket, udpthread.cpp transmitFrame): golden vectors,
every truncation, trailing garbage, a property test that only format errors come out (issue 24)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus import cannelloni as cn
from gatewaylab.bus.frame import CanFrame

CLASSIC = CanFrame(0x123, b"\x11\x22")
EXTENDED = CanFrame(0x1ABCDEF0, b"", extended=True)
REMOTE = CanFrame(0x456, b"", rtr=True, dlc=4)
FD = CanFrame(0x42, bytes(range(12)), fd=True, brs=True)
GOLDEN = bytes.fromhex(
    "02 00 07 0004"                                  # version 2, DATA, seq 7, count 4
    "00000123 02 1122"                               # 11-bit id, len 2, data
    "9ABCDEF0 00"                                    # CAN_EFF_FLAG | id, len 0
    "40000456 04"                                    # CAN_RTR_FLAG | id, len = DLC 4, no data
    "00000042 8C 01" + bytes(range(12)).hex())       # len 12 | CANFD_FRAME, flags BRS, data


def test_golden_packet_both_ways() -> None:
    """udp_format.md: header (version, op code, seq no, big-endian count); per frame can_id (big-endian, with
    linux/can.h flags), len (MSB: CAN FD, then flags), data; RTR frames carry no data."""
    assert cn.encode_packet([CLASSIC, EXTENDED, REMOTE, FD], 7) == GOLDEN
    assert cn.decode_packet(GOLDEN) == cn.Packet(7, (CLASSIC, EXTENDED, REMOTE, FD))


def test_wrong_version_or_op_code_drops_the_packet() -> None:
    """parseFrames(): 'Received wrong version' / 'Received wrong OP code': nothing delivered."""
    assert cn.decode_packet(b"\x01" + GOLDEN[1:]).error == "wrong version 1 (need 2)"
    assert cn.decode_packet(GOLDEN[:1] + b"\x01" + GOLDEN[2:]).error == "wrong op code 1 (DATA is 0)"
    assert cn.decode_packet(bytes.fromhex("0200050000")) == cn.Packet(5, ())   # empty: silently nothing


def test_every_truncation_keeps_the_frames_before_it() -> None:
    """parseFrames(): frames parsed before an incomplete one are delivered, then 'Received incomplete
    packet'; cut anywhere, the decoder reports an error and never raises."""
    whole = cn.decode_packet(GOLDEN).frames
    for cut in range(len(GOLDEN)):
        packet = cn.decode_packet(GOLDEN[:cut])
        assert packet.error is not None, cut
        assert packet.frames == whole[:len(packet.frames)]
    assert len(cn.decode_packet(GOLDEN[:-1]).frames) == 3


def test_trailing_bytes_after_count_frames_are_ignored() -> None:
    """parseFrames() reads ``count`` frames and stops."""
    assert cn.decode_packet(GOLDEN + b"garbage") == cn.Packet(7, (CLASSIC, EXTENDED, REMOTE, FD))


def test_lengths_beyond_can_fd_and_error_frames() -> None:
    """parseCANFrame(): len > CANFD_MAX_DLEN is rejected; a classic len 9..64 is no frame here; error
    frames (CAN_ERR_FLAG) are not put on a bus."""
    assert "len 65 > 64" in str(cn.decode_packet(bytes.fromhex("0200000001 00000001 41") + bytes(65)).error)
    assert cn.decode_packet(bytes.fromhex("0200000001 00000001 09") + bytes(9)).error is not None
    packet = cn.decode_packet(bytes.fromhex("0200000002 20000004 08 0000000000000000 00000001 00"))
    assert packet.frames == (CanFrame(1),) and packet.skipped == 1 and packet.error is None


def test_sender_sends_when_the_next_frame_might_not_fit_or_at_the_timeout() -> None:
    """udpthread.cpp transmitFrame(): the buffer goes out when it and one more frame header reach the
    payload size (MTU 1500 - 20 - 8), else when the buffer timeout (or a shorter per-id one) expires;
    prepareBuffer() numbers packets 0, 1, ... modulo 256 and keeps what does not fit."""
    s = cn.Sender(timeout=0.1, timeouts={(0x80, False): 0.0005})
    assert s.payload_size == 1472
    assert s.add(CanFrame(0x181, bytes(8))) == 0.1
    assert s.add(CanFrame(0x80)) == 0.0005
    first = s.packet()
    assert first is not None and first[:5] == bytes.fromhex("0200000002") and s.packet() is None
    n = 0
    while s.add(CanFrame(0x200, bytes(8))) > 0:
        n += 1
    assert (n + 1) * 13 + 5 + 5 >= 1472 > n * 13 + 5 + 5
    second = s.packet()
    assert second is not None and second[2] == 1 and len(second) <= 1472
    assert cn.HEADER.unpack_from(second)[3] + len(s.buffer) == n + 1    # what did not fit stays buffered
    assert len(second) + 13 > 1472
    s.buffer.clear()
    s.seq_no = 255
    s.add(CanFrame(1))
    assert s.packet()[2] == 255 and s.seq_no == 0   # type: ignore[index]


def test_sorted_buffers_and_sequence_gaps() -> None:
    """-s sorts a buffer by id (canfd_frame_comp); sequence gaps count lost packets, reordering does not."""
    s = cn.Sender(sort=True)
    for can_id in (0x300, 0x100, 0x200):
        s.add(CanFrame(can_id))
    assert [f.can_id for f in cn.decode_packet(s.packet() or b"").frames] == [0x100, 0x200, 0x300]
    t = cn.SeqTracker()
    for seq in (254, 255, 0, 3, 2, 4):
        t.seen(seq)
    assert t.missing == 1 and t.received == 6        # 1 never came, 2 came late


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=200),
                 st.binary(max_size=60).map(lambda b: bytes.fromhex("020000") + b)))
def test_any_datagram_gives_a_packet_never_an_exception(data: bytes) -> None:
    """Whatever arrives, the decoder returns frames it could read and, if any, the error."""
    packet = cn.decode_packet(data)
    assert all(isinstance(f, CanFrame) for f in packet.frames)
    if packet.error is None:
        assert cn.decode_packet(cn.encode_packet(packet.frames, packet.seq_no)).frames == packet.frames


@given(st.lists(st.builds(lambda i, n, fd: CanFrame(i, bytes(n), fd=fd) if fd or n <= 8 else CanFrame(i, bytes(8)),
                          st.integers(0, 0x7FF), st.sampled_from([0, 1, 8, 12, 64]), st.booleans()), max_size=40),
       st.integers(0, 255))
def test_encode_decode_round_trip(frames: list[CanFrame], seq: int) -> None:
    assert cn.decode_packet(cn.encode_packet(frames, seq)) == cn.Packet(seq, tuple(frames))
