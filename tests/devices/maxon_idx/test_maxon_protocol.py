"""The USB slave state machine (IDX guide 2.1, 2.2.1, 2.2.7, chapter 5, chapter 6) on fakes."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from maxon_helpers import SlaveHarness

from gatewaylab.devices.maxon_idx.codec import Frame, encode_frame
from gatewaylab.devices.maxon_idx.commands import (
    InitiateSegmentedRead,
    InitiateSegmentedReadReply,
    InitiateSegmentedWrite,
    ReadLss,
    ReadLssReply,
    ReadObject,
    ReadObjectReply,
    Request,
    SegmentRead,
    SegmentReadReply,
    SegmentWrite,
    SegmentWriteReply,
    SendLss,
    SendNmtService,
    StatusReply,
    WriteObject,
    decode_reply,
)
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode, idx_codes

GUIDE_REQUEST = bytes([0x90, 0x02, 0x60, 0x02, 0x01, 0xB0, 0x30, 0x00, 0x2E, 0x62])
GUIDE_RESPONSE = bytes([0x90, 0x02, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x01, 0x90, 0x90, 0x00, 0x00,
                        0x9A, 0x5C])


def ask(h: SlaveHarness, req: Request) -> object:
    (frame,) = h.feed(encode_frame(req.to_frame()))
    return decode_reply(req.opcode, frame)


def test_guide_example_answered_byte_for_byte(harness: SlaveHarness) -> None:
    """2.2.8: ReadObject 0x30B0:00 of node 1 answers exactly the guide's reception order."""
    harness.slave.receive(GUIDE_REQUEST)
    assert harness.wire == [GUIDE_RESPONSE]


def test_node_zero_is_local(harness: SlaveHarness) -> None:
    """Chapter 5 table 5-19: Node-ID 0 (gateway) -> execute."""
    assert ask(harness, ReadObject(0, 0x30B0, 0)) == ReadObjectReply(0, bytes([1, 0x90, 0, 0]))
    assert harness.gateway.uploads == []


def test_short_objects_padded_and_write_trimmed(harness: SlaveHarness) -> None:
    """2.1.1.1/2.1.2.1: 4 data bytes on the wire; a 2-byte object gets the low 2 bytes."""
    assert ask(harness, WriteObject(1, 0x6040, 0, bytes([0x0F, 0, 0, 0]))) == StatusReply(0)
    assert harness.objects.values[(0x6040, 0)] == bytearray([0x0F, 0])
    assert ask(harness, ReadObject(1, 0x6040, 0)) == ReadObjectReply(0, bytes([0x0F, 0, 0, 0]))


def test_object_errors_use_chapter6_codes(harness: SlaveHarness) -> None:
    """Chapter 6: object does not exist 0x06020000, read only 0x06010002, write only 0x06010001."""
    assert ask(harness, ReadObject(0, 0x5555, 0)) == ReadObjectReply(0x06020000)
    assert ask(harness, WriteObject(0, 0x1001, 0, bytes(4))) == StatusReply(0x06010002)
    assert ask(harness, ReadObject(0, 0x1011, 1)) == ReadObjectReply(0x06010001)
    assert ask(harness, ReadObject(0, 0x1008, 0)) == ReadObjectReply(SdoAbortCode.LENGTH_MISMATCH)


def test_bad_crc_answered_with_error_frame(harness: SlaveHarness) -> None:
    """2.2.2 Note + notes: a bad CRC gets 90 02 00 02 04 00 04 05 F1 E8."""
    harness.slave.receive(GUIDE_REQUEST[:-1] + b"\x00")
    assert harness.wire == [bytes([0x90, 0x02, 0x00, 0x02, 0x04, 0x00, 0x04, 0x05, 0xF1, 0xE8])]


def test_unknown_opcode_answered_illegal_command(harness: SlaveHarness) -> None:
    """2.2.2 Note: a bad OpCode gets an error frame; 0x0F00FFBF "Illegal command" (chapter 6)."""
    (frame,) = harness.feed(encode_frame(Frame(0x55, bytes(4))))
    assert frame == StatusReply(SdoAbortCode.ILLEGAL_COMMAND).to_frame()


def test_wrong_len_for_known_opcode(harness: SlaveHarness) -> None:
    """2.1.1.1: ReadObject has Len 2; another Len is a service parameter error, reply keeps its layout."""
    (frame,) = harness.feed(encode_frame(Frame(0x60, bytes(6))))
    assert decode_reply(0x60, frame) == ReadObjectReply(SdoAbortCode.LENGTH_MISMATCH)
    assert frame.length == 4


def test_segmented_read_local_string(harness: SlaveHarness) -> None:
    """2.1.1.2/2.1.1.3: first data in the initiate reply, then segments with toggle and last bit."""
    value = bytes(harness.objects.values[(0x1008, 0)])
    harness.slave.segment_size = 16
    r = ask(harness, InitiateSegmentedRead(0, 0x1008, 0))
    assert r == InitiateSegmentedReadReply(0, len(value), value[:16])
    got, toggle = bytearray(r.data), False
    while True:
        s = ask(harness, SegmentRead(toggle))
        assert isinstance(s, SegmentReadReply) and s.error == 0 and s.toggle == toggle
        got += s.data
        toggle = not toggle
        if s.last:
            break
    assert bytes(got) == value
    assert ask(harness, SegmentRead(toggle)) == SegmentReadReply(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)


def test_segment_sizes_up_to_255_and_odd_pad(harness: SlaveHarness) -> None:
    """2.1.1.2: Len 5..132, Length max 255; 2.1.1.3: dummy byte when length odd."""
    r = ask(harness, InitiateSegmentedRead(0, 0x2100, 1))
    assert isinstance(r, InitiateSegmentedReadReply) and r.total_length == 600 and len(r.data) == 255
    (frame,) = harness.feed(encode_frame(SegmentRead(False).to_frame()))
    assert frame.length == (6 + 255 + 1) // 2 == 131
    (frame,) = harness.feed(encode_frame(SegmentRead(True).to_frame()))
    s = decode_reply(0x62, frame)
    assert isinstance(s, SegmentReadReply) and s.last and len(s.data) == 90 and frame.length == 48


def test_toggle_must_alternate(harness: SlaveHarness) -> None:
    """Chapter 6: 0x05030000 toggle bit not alternated; the transfer is aborted."""
    ask(harness, InitiateSegmentedRead(0, 0x2100, 1))
    assert ask(harness, SegmentRead(True)) == SegmentReadReply(0x05030000)
    assert ask(harness, SegmentRead(False)) == SegmentReadReply(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)


def test_segmented_write_local(harness: SlaveHarness) -> None:
    """2.1.2.2/2.1.2.3: InitiateSegmentedWrite then SegmentWrite with toggle and last bit."""
    payload = bytes(range(256)) + b"tail!"
    assert ask(harness, InitiateSegmentedWrite(0, 0x2100, 1, len(payload))) == StatusReply(0)
    assert ask(harness, SegmentWrite(False, False, payload[:255])) == SegmentWriteReply(0, 255, False)
    (frame,) = harness.feed(encode_frame(SegmentWrite(True, True, payload[255:]).to_frame()))
    assert decode_reply(0x6A, frame) == SegmentWriteReply(0, 6, True)
    assert frame.length == 3
    assert bytes(harness.objects.values[(0x2100, 1)]) == payload


def test_segmented_write_toggle_and_length_errors(harness: SlaveHarness) -> None:
    """Chapter 6: toggle error 0x05030000; a length that does not match the announced total 0x06070010."""
    ask(harness, InitiateSegmentedWrite(0, 0x2100, 1, 10))
    assert ask(harness, SegmentWrite(True, False, b"abc")) == SegmentWriteReply(0x05030000)
    ask(harness, InitiateSegmentedWrite(0, 0x2100, 1, 10))
    assert ask(harness, SegmentWrite(False, True, b"abc")) == SegmentWriteReply(0x06070010)
    assert ask(harness, InitiateSegmentedWrite(0, 0x7777, 0, 4)) == StatusReply(0x06020000)


def test_segmented_write_to_a_read_only_object_refused_at_initiate(harness: SlaveHarness) -> None:
    """2.1.2.2 + chapter 6 0x06010002 "Write command to a read only object": refused when the
    transfer starts, before the host sends any segment; no segment is then accepted."""
    assert ask(harness, InitiateSegmentedWrite(0, 0x1008, 0, 300)) == StatusReply(0x06010002)
    assert ask(harness, SegmentWrite(False, False, bytes(255))) == \
        SegmentWriteReply(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)


def test_segmented_write_of_the_wrong_length_to_a_fixed_size_object(harness: SlaveHarness) -> None:
    """2.1.2.2 "Object Data Length (total number of bytes)" + chapter 6 0x06070010 "length or service
    parameter do not match": 0x30B0 holds 4 bytes, announcing 6 is refused at once; 4 is taken."""
    assert ask(harness, InitiateSegmentedWrite(0, 0x30B0, 0, 6)) == StatusReply(0x06070010)
    assert ask(harness, InitiateSegmentedWrite(0, 0x30B0, 0, 4)) == StatusReply(0)
    assert ask(harness, SegmentWrite(False, True, b"\x01\x02\x03\x04")) == SegmentWriteReply(0, 4, False)
    assert harness.objects.values[(0x30B0, 0)] == bytearray(b"\x01\x02\x03\x04")


def test_segmented_write_through_gateway_refused(harness: SlaveHarness) -> None:
    """2.1.2.2/2.1.2.3: "Note that gateway communication is not supported."""
    assert ask(harness, InitiateSegmentedWrite(5, 0x2100, 1, 10)) == StatusReply(SdoAbortCode.UNSUPPORTED_ACCESS)
    assert harness.gateway.downloads == []


def test_gateway_read_waits_for_bus_and_never_answers_twice(harness: SlaveHarness) -> None:
    """Chapter 5: node 2 -> SDO on the bus; 2.2.1/2.2.8: one request at a time, each answered in order."""
    h = harness
    assert h.feed(encode_frame(ReadObject(2, 0x6041, 0).to_frame())) == []
    assert h.feed(encode_frame(ReadObject(0, 0x30B0, 0).to_frame())) == []   # queued behind the first
    (node, index, sub, segmented, cb) = h.gateway.uploads[0]
    assert (node, index, sub, segmented) == (2, 0x6041, 0, False)
    cb(b"\x37\x02")
    replies = h.collect()
    assert [decode_reply(0x60, f) for f in replies] == [
        ReadObjectReply(0, b"\x37\x02\x00\x00"), ReadObjectReply(0, bytes([1, 0x90, 0, 0]))]


def test_gateway_abort_and_timeout_codes_pass_through(harness: SlaveHarness) -> None:
    """Chapter 5/6: the node's abort code is the reply's error; no answer -> 0x05040000."""
    h = harness
    h.feed(encode_frame(ReadObject(3, 0x1234, 0).to_frame()))
    h.gateway.uploads[-1][4](IdxRemoteError(0x06020000))
    replies = h.collect()
    h.feed(encode_frame(WriteObject(4, 0x6040, 0, bytes(4)).to_frame()))
    h.gateway.downloads[-1][4](IdxRemoteError(0x05040000))
    replies += h.collect()
    assert decode_reply(0x60, replies[0]) == ReadObjectReply(0x06020000)
    assert decode_reply(0x68, replies[1]) == StatusReply(0x05040000)


def test_gateway_segmented_read(harness: SlaveHarness) -> None:
    """2.1.1.2 via chapter 5: the value comes from a segmented SDO upload, served in USB segments."""
    h = harness
    h.feed(encode_frame(InitiateSegmentedRead(2, 0x1008, 0).to_frame()))
    assert h.gateway.uploads[-1][3] is True
    h.gateway.uploads[-1][4](b"EPOS4 remote")
    (frame,) = h.collect()
    assert decode_reply(0x81, frame) == InitiateSegmentedReadReply(0, 12, b"EPOS4 remote")


def test_remote_node_id_out_of_range(harness: SlaveHarness) -> None:
    """3.4: node ids are 1..127; 200 -> value range error 0x06090030."""
    assert ask(harness, ReadObject(200, 0x1000, 0)) == ReadObjectReply(0x06090030)


def test_nmt_and_lss(harness: SlaveHarness) -> None:
    """2.1.2.4 SendNMTService; 2.1.3.1 SendLSS; 2.1.3.2 ReadLSS only after SendLSS."""
    h = harness
    assert ask(h, SendNmtService(2, 1)) == StatusReply(0)
    assert h.gateway.nmt == [(2, 1)]
    assert ask(h, SendNmtService(2, 7)) == StatusReply(SdoAbortCode.VALUE_RANGE_EXCEEDED)
    assert ask(h, ReadLss(10)) == ReadLssReply(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE)
    assert ask(h, SendLss(bytes([0x5E]) + bytes(7))) == StatusReply(0)
    assert h.feed(encode_frame(ReadLss(10).to_frame())) == []
    timeout, cb = h.gateway.lss_reads[0]
    assert timeout == 0.01
    cb(bytes([0x5E, 5]) + bytes(6))
    (frame,) = h.collect()
    assert decode_reply(0x7B, frame) == ReadLssReply(0, bytes([0x5E, 5]) + bytes(6))


def test_read_lss_accepts_len_one_and_two(harness: SlaveHarness) -> None:
    """2.1.3.2: the guide says Len 2 but lists one WORD; both are accepted."""
    h = harness
    ask(h, SendLss(bytes(8)))
    h.feed(encode_frame(Frame(0x7B, bytes([100, 0, 0, 0]))))
    assert h.gateway.lss_reads[-1][0] == 0.1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=30), st.sampled_from([GUIDE_REQUEST, b"\x90\x02", b"\x90"])),
                max_size=15))
def test_random_streams_get_only_spec_replies(chunks: list[bytes]) -> None:
    """2.2.1/chapter 6: whatever the host sends, the slave never raises, and every byte it sends is a
    CRC-valid OpCode 0x00 frame whose error DWORD is 0 or a table 6-20 code."""
    h = SlaveHarness()
    h.objects.add(0x30B0, 0, bytes(4), size=4)
    for chunk in chunks:
        h.slave.receive(chunk)
    replies = h.collect()
    stats = h.slave.stats
    assert len(replies) == stats.replies
    # Every complete frame is answered exactly once (2.2.1 "All commands send an answer"), unless
    # it still waits for the bus; a bad CRC always with the Len 2 frame carrying 0x05040004.
    if not h.gateway.uploads and not h.gateway.downloads and not h.gateway.lss_reads:
        assert stats.replies == stats.requests + stats.crc_errors
    crc_answer = StatusReply(SdoAbortCode.CRC_ERROR).to_frame()
    assert stats.crc_errors <= replies.count(crc_answer)
    for frame in replies:
        assert frame.opcode == 0 and frame.length >= 2
        code = int.from_bytes(frame.data[:4], "little")
        assert code == 0 or code in idx_codes()


def test_host_decodes_len2_error_reply_for_any_command() -> None:
    """2.2.2 Note: a CRC error answer is Len 2 whatever was asked; the host still gets the code."""
    frame = StatusReply(SdoAbortCode.CRC_ERROR).to_frame()
    for opcode, cls in ((0x60, ReadObjectReply), (0x81, InitiateSegmentedReadReply), (0x62, SegmentReadReply),
                        (0x6A, SegmentWriteReply), (0x7B, ReadLssReply)):
        reply = decode_reply(opcode, frame)
        assert isinstance(reply, cls) and reply.error == 0x05040004


def test_segment_read_after_complete_initiate_gets_empty_last_segment(harness: SlaveHarness) -> None:
    """2.1.1.2/2.1.1.3: a value that fit in the initiate reply; a host looping until the last-segment
    bit gets one empty last segment, then the transfer is over."""
    r = ask(harness, InitiateSegmentedRead(0, 0x30B0, 0))
    assert r == InitiateSegmentedReadReply(0, 4, bytes([1, 0x90, 0, 0]))
    assert ask(harness, SegmentRead(False)) == SegmentReadReply(0, False, True, b"")
    assert ask(harness, SegmentRead(True)) == SegmentReadReply(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)


def test_requests_behind_a_running_one_are_answered_in_order_up_to_the_queue_depth(
        harness: SlaveHarness) -> None:
    """2.2.8 D "IDX cannot process data simultaneously": requests sent while a gateway read runs are
    answered afterwards, in order, one reply each; beyond 64 waiting requests the rest are counted
    as overflows and get no answer (docs/decisions.md)."""
    from gatewaylab.devices.maxon_idx.protocol import MAX_QUEUED

    h = harness
    assert h.feed(encode_frame(ReadObject(2, 0x6041, 0).to_frame())) == []
    local = encode_frame(ReadObject(0, 0x30B0, 0).to_frame())
    assert h.feed(local * (MAX_QUEUED + 3)) == []
    assert h.slave.stats.overflows == 3
    h.gateway.uploads[0][4](b"\x37\x02")
    replies = [decode_reply(0x60, f) for f in h.collect()]
    assert replies == [ReadObjectReply(0, b"\x37\x02\x00\x00")] + [ReadObjectReply(0, bytes([1, 0x90, 0, 0]))] * 64
