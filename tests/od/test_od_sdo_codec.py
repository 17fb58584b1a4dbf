"""The SDO codec shared by the CANopen server, client and CoE (CiA 301 7.2.4.3, figures 20-33)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.od import SdoAbort, SdoAbortCode
from gatewaylab.od import sdo as codec


def test_golden_frames() -> None:
    """CiA 301 7.2.4.3: expedited upload response 0x43/0x4F, download response 0x60, abort 0x80,
    last segment with n unused bytes, end block with n and CRC."""
    assert codec.expedited_upload_response(0x1018, 1, b"\x78\x56\x34\x12") == bytes.fromhex("4318100178563412")
    assert codec.expedited_upload_response(0x1001, 0, b"\x05") == bytes.fromhex("4f01100005000000")
    assert codec.download_response(0x6040, 0) == bytes.fromhex("6040600000000000")
    assert codec.abort(0x1000, 0, 0x06020000) == bytes.fromhex("8000100000000206")
    assert codec.segment(0x00, 1, b"abc", True) == bytes.fromhex("19616263") + bytes(4)     # t=1, n=4, c=1
    assert codec.segment_ack(0x60, 1) == bytes.fromhex("7000000000000000")
    assert codec.block_end(0xC1, 9, 0xBEEF) == bytes.fromhex("d5efbe0000000000")               # n = 5
    assert codec.expedited_download_request(0x6060, 0, b"\x01") == bytes.fromhex("2f60600001000000")


@given(st.binary(min_size=0, max_size=200), st.integers(min_value=7, max_value=60))
def test_segmented_upload_and_download_round_trip(data: bytes, max_segment: int) -> None:
    """CiA 301 7.2.4.3.6-9 / ETG.1000.6 CoE segments: what the upload side sends, the download side
    collects, with alternating toggle bits; only the segment sizes differ between CAN and CoE."""
    up = codec.SegmentedUpload(0x2000, 1, data, max_segment)
    down = codec.SegmentedDownload(0x2000, 1, len(data), len(data), SdoAbortCode.LENGTH_TOO_HIGH)
    toggle = 0
    while True:
        frame, last = up.segment(toggle << 4)
        if max_segment == 7:
            assert len(frame) == 8
        seen_toggle, seen_last = down.segment(frame)
        assert (seen_toggle, seen_last) == (toggle, last)
        toggle ^= 1
        if last:
            break
    codec.check_size(len(down.buf), down.size)
    assert bytes(down.buf) == data


def test_toggle_and_size_errors() -> None:
    """CiA 301 abort codes: 0x05030000 toggle bit not alternated, 0x06070013 / 0x06070010 size."""
    up = codec.SegmentedUpload(0x2000, 0, bytes(20))
    with pytest.raises(SdoAbort) as err:
        up.segment(0x10)
    assert err.value.code == SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED
    with pytest.raises(SdoAbort) as err:
        codec.check_size(3, 4)
    assert err.value.code == SdoAbortCode.LENGTH_TOO_LOW
    with pytest.raises(SdoAbort) as err:
        codec.check_size(5, 4)
    assert err.value.code == SdoAbortCode.LENGTH_MISMATCH


@given(st.binary(min_size=0, max_size=200), st.integers(min_value=7, max_value=60))
def test_client_halves_talk_to_server_halves(data: bytes, max_segment: int) -> None:
    """CiA 301 7.2.4.3.3-7.2.4.3.6: the client's segment requests (one toggle, starting at 0) are
    what the server halves accept, and the client collects exactly what the server sent; the
    same state machines serve CAN (7-byte segments) and CoE (longer ones)."""
    # upload: client requests, server answers
    server_up = codec.SegmentedUpload(0x2000, 1, data, max_segment)
    client_up = codec.ClientSegmentedUpload(len(data))
    while not client_up.done:
        answer, _last = server_up.segment(client_up.request()[0])
        client_up.response(answer)
    assert client_up.data == data
    # download: client segments, server acknowledges with the segment's toggle
    server_down = codec.SegmentedDownload(0x2000, 1, len(data), len(data), SdoAbortCode.LENGTH_TOO_HIGH)
    client_down = codec.ClientSegmentedDownload(data, max_segment)
    while True:
        toggle, last = server_down.segment(client_down.next_segment())
        client_down.response(codec.segment_ack(codec.ServerCommand.DOWNLOAD_SEGMENT << 5, toggle))
        if last:
            break
    assert client_down.done and bytes(server_down.buf) == data


def test_client_detects_server_errors() -> None:
    """CiA 301 7.2.4.3.16 abort codes a client raises itself: 0x05030000 toggle bit not alternated,
    0x05040001 a segment of the wrong kind, 0x06070010 a total other than the announced size."""
    up = codec.ClientSegmentedUpload(10)
    with pytest.raises(SdoAbort) as err:
        up.response(codec.segment(0x00, 1, b"abc", False))              # toggle 1 where 0 is due
    assert err.value.code == SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED
    with pytest.raises(SdoAbort) as err:
        up.response(codec.segment_ack(0x20, 0))                         # a download segment response
    assert err.value.code == SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN
    up.response(codec.segment(0x00, 0, b"abcdefg", False))
    with pytest.raises(SdoAbort) as err:
        up.response(codec.segment(0x00, 1, b"hi", True))                # 9 bytes, 10 announced
    assert err.value.code == SdoAbortCode.LENGTH_MISMATCH
    down = codec.ClientSegmentedDownload(bytes(20))
    down.next_segment()
    with pytest.raises(SdoAbort) as err:
        down.response(codec.segment_ack(0x20, 1))                        # answers toggle 1, 0 was sent
    assert err.value.code == SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED
    # CoE: an initiate response that carried every announced byte needs no segment
    assert codec.ClientSegmentedUpload(3, bytearray(b"abc")).done


@given(st.binary(min_size=0, max_size=400), st.integers(min_value=1, max_value=127),
       st.integers(min_value=1, max_value=127), st.integers(min_value=0, max_value=60))
def test_block_sender_and_receiver_round_trip_with_a_lost_segment(data: bytes, tx_blksize: int, rx_blksize: int,
                                                                  lost: int) -> None:
    """CiA 301 7.2.4.3.9-7.2.4.3.16 (issue 22 'one SDO block-ack handler for client and server'): the one
    sender and one receiver of a block transfer deliver every byte and the CRC, also when segment
    number ``lost`` of the first sub-block never arrives (the receiver acknowledges what came in
    sequence, the sender rewinds to it). A lost last segment of a sub-block is not acknowledged at all:
    that ends in the SDO timeout, outside these halves."""
    sender = codec.BlockSender(data, tx_blksize)
    receiver = codec.BlockReceiver(rx_blksize)
    sender.blksize = receiver.blksize     # the initiate exchange agrees on the receiver's block size
    first = True
    while True:
        ack = None
        frames = sender.sub_block()
        for seq, frame in enumerate(frames, 1):
            if first and seq == lost < len(frames):
                continue
            ack = receiver.segment(frame) or ack
        first = False
        assert ack is not None and ack[0] == codec.CS_BLOCK_ACK
        if sender.ack(ack):
            break
    assert receiver.last
    assert receiver.end(sender.end(crc=True), len(data), crc=True) == data


def test_block_receiver_and_sender_abort_codes() -> None:
    """CiA 301 7.2.4.3.10/7.2.4.3.16: sequence number 0 or beyond blksize 0x05040003, an ackseq beyond
    the segments sent 0x05040003, a block size outside 1..127 0x05040002, a wrong CRC 0x05040004."""
    receiver = codec.BlockReceiver(4)
    for cs in (0x00, 0x05):
        with pytest.raises(SdoAbort) as err:
            receiver.segment(bytes((cs,)) + bytes(7))
        assert err.value.code == SdoAbortCode.INVALID_SEQUENCE_NUMBER
    sender = codec.BlockSender(bytes(20), 4)
    assert len(sender.sub_block()) == 3
    for ack, code in ((codec.block_ack(4, 4), SdoAbortCode.INVALID_SEQUENCE_NUMBER),
                      (codec.block_ack(3, 0), SdoAbortCode.INVALID_BLOCK_SIZE)):
        with pytest.raises(SdoAbort) as err:
            sender.ack(ack)
        assert err.value.code == code
    assert receiver.segment(codec.block_segment(1, b"abc", True)) == codec.block_ack(1, 4)
    with pytest.raises(SdoAbort) as err:
        receiver.end(codec.block_end(0xC1, 3, 0x1234), 3, crc=True)
    assert err.value.code == SdoAbortCode.CRC_ERROR
