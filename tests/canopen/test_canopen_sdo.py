"""SDO server interop with python-canopen as the client, and exact-frame abort code paths.

Manual: IDX Communication Guide 3.3.3.2 (SDO object) and chapter 6 table 6-20 (abort codes);
CiA 301 7.2.4 for the protocols the guide only names.
"""

from __future__ import annotations

import struct

import canopen
import pytest
from canopen_testkit import barrier, remote_for

from gatewaylab.od import SdoAbort, SdoAbortCode
from gatewaylab.od.crc import crc16_ccitt


def abort_code(answer: bytes | None) -> int:
    assert answer is not None, "the node stayed silent"
    assert answer[0] == 0x80, f"not an abort: {answer.hex()}"
    return int(struct.unpack_from("<I", answer, 4)[0])


def test_crc16_check_value() -> None:
    """CiA 301 7.2.4.3.16: CRC x^16+x^12+x^5+1, init 0 -> the CCITT/XMODEM check value 0x31C3."""
    assert crc16_ccitt(b"123456789") == 0x31C3


def test_expedited_upload_of_every_type(make_node, network) -> None:
    """IDX 3.3.3.2: any entry reads back through the SDO as its little-endian value (canopen decodes it)."""
    node = make_node()
    remote = remote_for(network, node)
    for index, sub in [(0x2000, 0), (0x2003, 0), (0x2004, 0), (0x2006, 0), (0x2007, 0), (0x2008, 0),
                       (0x2009, 0), (0x200A, 0), (0x200B, 0), (0x200C, 0), (0x200E, 0), (0x200F, 0),
                       (0x2100, 2), (0x2200, 3), (0x1018, 0), (0x1014, 0)]:
        var = remote.sdo[index] if sub == 0 and index not in (0x2100, 0x2200, 0x1018) else remote.sdo[index][sub]
        assert var.raw == node.get(index, sub), hex(index)
    assert remote.sdo[0x1014].raw == 0x80 + 5            # $NODEID+0x80 resolved
    assert remote.sdo[0x1200][1].raw == 0x605


def test_expedited_download_changes_value(make_node, network) -> None:
    """IDX 3.3.3.2: an expedited download writes the object."""
    node = make_node()
    remote = remote_for(network, node)
    remote.sdo[0x2000].raw = 0xCAFEBABE
    remote.sdo[0x2007].raw = -123456
    remote.sdo[0x2008].raw = 3.25
    remote.sdo[0x200C].raw = False
    assert node.get(0x2000) == 0xCAFEBABE
    assert node.get(0x2007) == -123456
    assert node.get(0x2008) == 3.25
    assert node.get(0x200C) is False


def test_segmented_upload_and_download(make_node, network) -> None:
    """CiA 301 7.2.4.3.4-7: more than 4 bytes travel in 7-byte segments with an alternating toggle bit."""
    node = make_node()
    remote = remote_for(network, node)
    assert remote.sdo[0x2001].raw == "gatewaylab CANopen node"
    assert remote.sdo.upload(0x2002, 0) == bytes(range(256)) * 4
    remote.sdo[0x2001].raw = "a somewhat longer visible string"
    assert node.get(0x2001) == "a somewhat longer visible string"
    remote.sdo.download(0x2002, 0, bytes(range(100)), force_segment=True)
    assert node.get(0x2002) == bytes(range(100))
    remote.sdo.download(0x2000, 0, b"\x01\x02\x03\x04", force_segment=True)
    assert node.get(0x2000) == 0x04030201


def test_block_upload_with_crc(make_node, network) -> None:
    """CiA 301 7.2.4.3.13-15: block upload in sub-blocks of <=127 segments, CRC checked by the client."""
    node = make_node()
    remote = remote_for(network, node)
    with remote.sdo.open(0x2002, 0, "rb", block_transfer=True) as stream:
        data = stream.read()
    assert data == bytes(range(256)) * 4                  # 1024 bytes = 2 sub-blocks
    assert node.sdo.state.name == "IDLE"
    with remote.sdo.open(0x2002, 0, "rb", block_transfer=True, request_crc_support=False) as stream:
        assert stream.read() == bytes(range(256)) * 4


def test_block_download_with_crc(make_node, network) -> None:
    """CiA 301 7.2.4.3.9-11: block download; the server checks size and CRC before it writes."""
    node = make_node()
    remote = remote_for(network, node)
    payload = bytes((i * 7) & 0xFF for i in range(2000))
    with remote.sdo.open(0x2002, 0, "wb", size=len(payload), block_transfer=True) as stream:
        stream.write(payload)
    assert node.get(0x2002) == payload
    with remote.sdo.open(0x2001, 0, "wb", size=14, block_transfer=True) as stream:
        stream.write(b"block download")
    assert node.get(0x2001) == "block download"


@pytest.mark.parametrize(("index", "sub", "code"), [
    (0x3000, 0, SdoAbortCode.OBJECT_DOES_NOT_EXIST),
    (0x2200, 2, SdoAbortCode.SUBINDEX_DOES_NOT_EXIST),
    (0x2005, 0, SdoAbortCode.WRITE_ONLY),
])
def test_upload_aborts(make_node, network, index: int, sub: int, code: int) -> None:
    """IDX table 6-20: unknown object 0x06020000, unknown sub-index 0x06090011, write-only 0x06010001."""
    node = make_node()
    remote = remote_for(network, node)
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo.upload(index, sub)
    assert info.value.code == code


@pytest.mark.parametrize(("index", "sub", "data", "code"), [
    (0x3000, 0, b"\x01", SdoAbortCode.OBJECT_DOES_NOT_EXIST),
    (0x2200, 7, b"\x01", SdoAbortCode.SUBINDEX_DOES_NOT_EXIST),
    (0x2004, 0, b"\x01", SdoAbortCode.READ_ONLY),
    (0x2006, 0, b"\x01\x02", SdoAbortCode.READ_ONLY),                 # CONST
    (0x1018, 1, b"\x01\x02\x03\x04", SdoAbortCode.READ_ONLY),
    (0x2011, 0, b"\x01\x02\x03\x04", SdoAbortCode.LENGTH_MISMATCH),   # too long: 0x06070010 (the IDX has no 0x06070012)
    (0x2000, 0, b"\x01", SdoAbortCode.LENGTH_TOO_LOW),
    (0x2003, 0, struct.pack("<h", 101), SdoAbortCode.VALUE_RANGE_EXCEEDED),
    (0x2003, 0, struct.pack("<h", -101), SdoAbortCode.VALUE_RANGE_EXCEEDED),
    (0x200C, 0, b"\x02", SdoAbortCode.VALUE_RANGE_EXCEEDED),
    (0x1003, 0, b"\x01", SdoAbortCode.VALUE_RANGE_EXCEEDED),          # 0x1003:00 only accepts 0
    (0x200E, 0, b"\x01\x02", SdoAbortCode.LENGTH_TOO_LOW),
])
def test_download_aborts(make_node, network, index: int, sub: int, data: bytes, code: int) -> None:
    """IDX table 6-20: object/sub-index unknown, read only, length too high/low, value range."""
    node = make_node()
    remote = remote_for(network, node)
    before = dict(node.od.values)
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo.download(index, sub, data)
    assert info.value.code == code
    assert node.od.values == before                      # nothing was written


def test_segmented_download_with_wrong_size_is_refused(make_node, network) -> None:
    """IDX table 6-20: the size indicated for a fixed-size object must match its length."""
    node = make_node()
    remote = remote_for(network, node)
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo.download(0x2000, 0, b"\x00" * 9, force_segment=True)
    assert info.value.code == SdoAbortCode.LENGTH_MISMATCH
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo.download(0x200A, 0, b"\x00" * 5, force_segment=True)
    assert info.value.code == SdoAbortCode.LENGTH_TOO_LOW


def test_wrong_nmt_state_abort(make_node, network) -> None:
    """IDX table 6-20 0x0F00FFC0: an object writable only outside Operational refuses writes there."""
    node = make_node()
    remote = remote_for(network, node)
    remote.sdo[0x2010].raw = 8
    remote.nmt.state = "OPERATIONAL"
    barrier(remote)
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo[0x2010].raw = 9
    assert info.value.code == SdoAbortCode.WRONG_NMT_STATE
    assert node.get(0x2010) == 8


def test_hook_abort_undoes_write_and_hook_crash_is_general_error(make_node, network) -> None:
    """IDX table 6-20: device logic refuses a value with its code; a failing hook is 0x08000000, no crash."""
    node = make_node()
    remote = remote_for(network, node)

    def refuse(index: int, sub: int, value: int) -> None:
        if value == 13:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE)
        if value == 14:
            raise RuntimeError("bug in device code")

    node.on_write(0x2000, refuse)
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo[0x2000].raw = 13
    assert info.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE
    assert node.get(0x2000) == 0x12345678
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo[0x2000].raw = 14
    assert info.value.code == SdoAbortCode.GENERAL_ERROR
    assert node.stats["hook_errors"] == 1
    assert node.get(0x2000) == 0x12345678                 # undone as well
    remote.sdo[0x2000].raw = 15
    assert node.get(0x2000) == 15


# -- exact frames -------------------------------------------------------------------------------

def test_expedited_golden_frames(make_node, raw) -> None:
    """CiA 301 7.2.4.3.3/6: expedited upload answer 0x4B (2 bytes) and download answer 0x60."""
    make_node()
    assert raw.sdo(5, [0x40, 0x11, 0x20, 0x00]) == bytes([0x4B, 0x11, 0x20, 0x00, 0x11, 0x11, 0, 0])
    assert raw.sdo(5, [0x2B, 0x11, 0x20, 0x00, 0x34, 0x12]) == bytes([0x60, 0x11, 0x20, 0, 0, 0, 0, 0])
    assert raw.sdo(5, [0x40, 0x11, 0x20, 0x00]) == bytes([0x4B, 0x11, 0x20, 0x00, 0x34, 0x12, 0, 0])
    # e=1, s=0: size not indicated -> the object's own size is taken from the 4 data bytes
    assert raw.sdo(5, [0x22, 0x00, 0x20, 0x00, 1, 2, 3, 4]) == bytes([0x60, 0x00, 0x20, 0, 0, 0, 0, 0])
    assert raw.sdo(5, [0x40, 0x00, 0x20, 0x00]) == bytes([0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4])


def test_segmented_upload_toggle_error(make_node, raw) -> None:
    """IDX table 6-20 0x05030000: a segment request whose toggle bit did not alternate is aborted."""
    make_node()
    answer = raw.sdo(5, [0x40, 0x01, 0x20, 0x00])
    assert answer is not None and answer[0] == 0x41 and struct.unpack_from("<I", answer, 4)[0] == 23
    first = raw.sdo(5, [0x60])
    assert first == b"\x00" + b"gateway"
    assert abort_code(raw.sdo(5, [0x60])) == SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED   # toggle must be 1 now
    assert raw.sdo(5, [0x70]) is not None                                  # back to idle: unknown
    assert abort_code(raw.sdo(5, [0x70])) == SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN


def test_segmented_download_toggle_error(make_node, raw) -> None:
    """IDX table 6-20 0x05030000 during a segmented download."""
    node = make_node()
    assert raw.sdo(5, [0x21, 0x01, 0x20, 0x00, 10, 0, 0, 0]) == bytes([0x60, 0x01, 0x20, 0, 0, 0, 0, 0])
    assert raw.sdo(5, [0x00, *b"abcdefg"]) == bytes([0x20, 0, 0, 0, 0, 0, 0, 0])
    assert abort_code(raw.sdo(5, [0x00 | (4 << 1) | 1, *b"hij"])) == SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED
    assert node.get(0x2001) == "gatewaylab CANopen node"


def test_segmented_download_frames(make_node, raw) -> None:
    """CiA 301 7.2.4.3.5: n = unused bytes of the last segment, c = last; answer toggles 0x20/0x30."""
    node = make_node()
    assert raw.sdo(5, [0x21, 0x01, 0x20, 0x00, 10, 0, 0, 0]) is not None
    assert raw.sdo(5, [0x00, *b"abcdefg"]) == bytes([0x20]) + bytes(7)
    assert raw.sdo(5, [0x10 | (4 << 1) | 1, *b"hij"]) == bytes([0x30]) + bytes(7)
    assert node.get(0x2001) == "abcdefghij"


def test_sdo_server_timeout_on_the_clock(make_node, raw, clock) -> None:
    """IDX table 6-20 0x05040000: a transfer left hanging is aborted when the server's timer expires."""
    node = make_node()
    assert raw.sdo(5, [0x21, 0x02, 0x20, 0x00, 20, 0, 0, 0]) is not None
    raw.received.clear()
    clock.advance(node.sdo.timeout * 0.9)
    assert raw.take(0x585) == []
    clock.advance(node.sdo.timeout * 0.2)
    frames = raw.take(0x585)
    assert len(frames) == 1 and abort_code(frames[0].data) == SdoAbortCode.SDO_PROTOCOL_TIMED_OUT
    assert frames[0].data[1:4] == bytes([0x02, 0x20, 0x00])


@pytest.mark.parametrize("cs", [0xE0, 0xE5, 0xFF])
def test_unknown_command_specifier(make_node, raw, cs: int) -> None:
    """IDX table 6-20 0x05040001: ccs 7 does not exist."""
    make_node()
    assert abort_code(raw.sdo(5, [cs, 0x00, 0x20, 0x00])) == SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN


def test_segment_without_transfer_is_unknown_command(make_node, raw) -> None:
    """CiA 301: a segment request outside a segmented transfer is 0x05040001."""
    make_node()
    assert abort_code(raw.sdo(5, [0x60])) == SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN
    assert abort_code(raw.sdo(5, [0x00, 1, 2, 3, 4, 5, 6, 7])) == SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN


def test_client_abort_is_not_answered(make_node, raw) -> None:
    """CiA 301 7.2.4.3.17: the abort service is unconfirmed; the transfer ends."""
    node = make_node()
    assert raw.sdo(5, [0x40, 0x02, 0x20, 0x00]) is not None
    assert raw.sdo(5, [0x80, 0x02, 0x20, 0x00, 0, 0, 4, 5]) is None
    assert node.sdo.state.name == "IDLE"


def test_short_sdo_frames_are_ignored(make_node, raw) -> None:
    """CiA 301 7.2.4: SDO frames have 8 data bytes; others are counted and not answered."""
    node = make_node()
    raw.received.clear()
    raw.send(0x605, [0x40, 0x00, 0x20])
    assert raw.take(0x585) == []
    assert node.sdo.ignored == 1


def test_block_download_crc_error(make_node, raw) -> None:
    """IDX table 6-20 0x05040004: a block download whose CRC does not match is aborted, not written."""
    node = make_node()
    answer = raw.sdo(5, [0xC6, 0x01, 0x20, 0x00, 10, 0, 0, 0])
    assert answer is not None and answer[0] == 0xA4 and answer[4] == 127
    raw.received.clear()
    raw.push(5, [0x01, *b"abcdefg"])
    assert raw.take(0x585) == []                         # no answer within the sub-block
    raw.push(5, [0x82, *b"hij\0\0\0\0"])
    ack = raw.take(0x585)
    assert [f.data for f in ack] == [bytes([0xA2, 2, 127, 0, 0, 0, 0, 0])]
    bad_crc = crc16_ccitt(b"abcdefghij") ^ 0x1
    assert abort_code(raw.sdo(5, struct.pack("<BH5x", 0xC1 | (4 << 2), bad_crc))) == SdoAbortCode.CRC_ERROR
    assert node.get(0x2001) == "gatewaylab CANopen node"


def test_block_download_golden_and_lost_segment(make_node, raw) -> None:
    """CiA 301 7.2.4.3.10: after a lost segment the server acknowledges the last good one; the
    client repeats from there and the end frame carries the CRC."""
    node = make_node()
    node.sdo.block_size = 3
    assert raw.sdo(5, [0xC6, 0x01, 0x20, 0x00, 17, 0, 0, 0]) == bytes([0xA4, 0x01, 0x20, 0x00, 3, 0, 0, 0])
    raw.received.clear()
    raw.push(5, [0x01, *b"ABCDEFG"])
    raw.push(5, [0x03, *b"OPQRSTU"])                # segment 2 lost, 3 arrives
    assert [f.data[:3] for f in raw.take(0x585)] == [bytes([0xA2, 1, 3])]
    raw.push(5, [0x01, *b"HIJKLMN"])
    raw.push(5, [0x82, *b"OPQ\0\0\0\0"])
    assert [f.data[:2] for f in raw.take(0x585)] == [bytes([0xA2, 2])]
    crc = crc16_ccitt(b"ABCDEFGHIJKLMNOPQ")
    assert raw.sdo(5, struct.pack("<BH5x", 0xC1 | (4 << 2), crc)) == bytes([0xA1]) + bytes(7)
    assert node.get(0x2001) == "ABCDEFGHIJKLMNOPQ"


def test_block_invalid_sequence_and_block_size(make_node, raw) -> None:
    """IDX/CiA 301: sequence number 0 is 0x05040003; a block size of 0 or >127 is 0x05040002."""
    make_node()
    assert raw.sdo(5, [0xC6, 0x01, 0x20, 0x00, 10, 0, 0, 0]) is not None
    assert abort_code(raw.sdo(5, [0x00, 1, 2, 3, 4, 5, 6, 7])) == SdoAbortCode.INVALID_SEQUENCE_NUMBER
    assert abort_code(raw.sdo(5, [0xA4, 0x02, 0x20, 0x00, 0, 0, 0, 0])) == SdoAbortCode.INVALID_BLOCK_SIZE
    assert abort_code(raw.sdo(5, [0xA4, 0x02, 0x20, 0x00, 128, 0, 0, 0])) == SdoAbortCode.INVALID_BLOCK_SIZE


def test_block_upload_golden_frames_and_protocol_switch(make_node, raw) -> None:
    """CiA 301 7.2.4.3.13: initiate answer 0xC6 + size, segments with c on the last, end 0xC1|n<<2 + CRC;
    with a protocol switch threshold >= size the server answers with a normal upload."""
    make_node()
    assert raw.sdo(5, [0xA4, 0x01, 0x20, 0x00, 127, 0, 0, 0]) == \
        bytes([0xC6, 0x01, 0x20, 0x00, 23, 0, 0, 0])
    raw.received.clear()
    raw.push(5, [0xA3])
    segs = [f.data for f in raw.take(0x585)]
    assert [s[0] for s in segs] == [1, 2, 3, 0x84]
    assert b"".join(s[1:] for s in segs)[:23] == b"gatewaylab CANopen node"
    end = raw.sdo(5, [0xA2, 4, 127])
    assert end == struct.pack("<BH5x", 0xC1 | (5 << 2), crc16_ccitt(b"gatewaylab CANopen node"))
    assert raw.sdo(5, [0xA1]) is None
    # pst = 4 and a 4-byte object: expedited answer instead of a block
    assert raw.sdo(5, [0xA4, 0x00, 0x20, 0x00, 127, 4, 0, 0]) == bytes([0x43, 0x00, 0x20, 0x00, 0x78, 0x56, 0x34, 0x12])


def test_block_upload_repeats_after_lost_segment(make_node, raw) -> None:
    """CiA 301 7.2.4.3.14: ackseq < segments sent -> the server repeats from ackseq + 1."""
    make_node()
    raw.sdo(5, [0xA4, 0x01, 0x20, 0x00, 127, 0, 0, 0])
    raw.push(5, [0xA3])
    raw.take(0x585)
    raw.push(5, [0xA2, 1, 127])                     # only the first one arrived
    segs = [f.data for f in raw.take(0x585)]
    assert [s[0] for s in segs] == [1, 2, 0x83]
    assert segs[0][1:] == b"lab CAN"


def test_stopped_node_does_not_answer_sdo(make_node, raw) -> None:
    """IDX table 3-11: in Stopped only NMT, LSS and heartbeat work; SDO requests stay unanswered."""
    node = make_node()
    raw.send(0x000, [0x02, 5])
    assert node.nmt_state.name == "STOPPED"
    assert raw.sdo(5, [0x40, 0x00, 0x10, 0x00]) is None
    raw.send(0x000, [0x80, 5])
    assert raw.sdo(5, [0x40, 0x00, 0x10, 0x00]) is not None


def test_sdo_server_timeout_restarts_with_each_request(make_node, raw, clock) -> None:
    """IDX table 6-20 0x05040000: the timeout runs from the client's last request -- a segment
    received restarts it, and a transfer that ended leaves nothing that aborts the next one early."""
    node = make_node()
    timeout = node.sdo.timeout
    assert raw.sdo(5, [0x21, 0x02, 0x20, 0x00, 14, 0, 0, 0]) is not None
    clock.advance(timeout * 0.6)
    assert raw.sdo(5, [0x00, *b"abcdefg"]) == bytes([0x20]) + bytes(7)
    raw.received.clear()
    clock.advance(timeout * 0.6)                # 1.2 timeouts after the initiate, 0.6 after the segment
    assert raw.take(0x585) == []
    assert raw.sdo(5, [0x11, *b"hijklmn"]) == bytes([0x30]) + bytes(7)     # last segment: done
    assert node.get(0x2002) == b"abcdefghijklmn"
    clock.advance(timeout * 0.5)
    assert raw.sdo(5, [0x21, 0x02, 0x20, 0x00, 14, 0, 0, 0]) is not None    # a new transfer
    raw.received.clear()
    clock.advance(timeout * 0.9)                # past the first transfer's deadlines, not this one's
    assert raw.take(0x585) == []
    clock.advance(timeout * 0.2)
    assert [abort_code(f.data) for f in raw.take(0x585)] == [SdoAbortCode.SDO_PROTOCOL_TIMED_OUT]


def test_block_transfer_timeouts(make_node, raw, clock) -> None:
    """IDX table 6-20 0x05040000: a block upload waiting for the client's acknowledgement and a
    block download waiting for the next segment are aborted when the server's timer expires."""
    node = make_node()
    raw.sdo(5, [0xA4, 0x01, 0x20, 0x00, 127, 0, 0, 0])
    raw.push(5, [0xA3])
    raw.received.clear()
    clock.advance(node.sdo.timeout + 0.01)
    assert [abort_code(f.data) for f in raw.take(0x585)] == [SdoAbortCode.SDO_PROTOCOL_TIMED_OUT]
    raw.sdo(5, [0xC6, 0x01, 0x20, 0x00, 30, 0, 0, 0])
    raw.push(5, [0x01, *b"abcdefg"])
    raw.received.clear()
    clock.advance(node.sdo.timeout + 0.01)
    assert [abort_code(f.data) for f in raw.take(0x585)] == [SdoAbortCode.SDO_PROTOCOL_TIMED_OUT]
    assert node.sdo.state.name == "IDLE"


def test_node_read_write_api_is_the_sdo_view(make_node) -> None:
    """Contract: node.read/write give exactly what an SDO client gets, with the same abort codes;
    get/set are typed local access without checks."""
    node = make_node()
    assert node.read(0x2011, 0) == b"\x11\x11"
    node.write(0x2011, 0, b"\x34\x12")
    assert node.get(0x2011) == 0x1234
    for call, code in [(lambda: node.read(0x2005, 0), SdoAbortCode.WRITE_ONLY),
                       (lambda: node.write(0x2004, 0, b"\x01"), SdoAbortCode.READ_ONLY),
                       (lambda: node.write(0x2003, 0, b"\x65\x00"), SdoAbortCode.VALUE_RANGE_EXCEEDED),
                       (lambda: node.write(0x2011, 0, b"\x01"), SdoAbortCode.LENGTH_TOO_LOW),
                       (lambda: node.read(0x4000, 0), SdoAbortCode.OBJECT_DOES_NOT_EXIST)]:
        with pytest.raises(SdoAbort) as info:
            call()
        assert info.value.code == code
    node.set(0x2004, 0, 7)                   # read-only for SDO, settable by the device
    assert node.read(0x2004, 0) == b"\x07"
    refreshed: list[tuple[int, int]] = []
    node.on_read(0x2004, lambda i, s: (refreshed.append((i, s)), node.set(0x2004, 0, 9)))
    assert node.read(0x2004, 0) == b"\x09" and refreshed == [(0x2004, 0)]


def test_segmented_download_without_size_and_upload_golden(make_node, raw) -> None:
    """CiA 301 7.2.4.3.4-7: initiate 0x20 (size not indicated) is accepted; a segmented upload
    answers 0x41 + size, then 0x00/0x10 segments, the last with n unused bytes and c set."""
    node = make_node()
    assert raw.sdo(5, [0x20, 0x01, 0x20, 0x00]) == bytes([0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0])
    assert raw.sdo(5, [0x00 | (6 << 1) | 1, *b"z"]) == bytes([0x20]) + bytes(7)
    assert node.get(0x2001) == "z"
    node.set(0x2001, 0, "ABCDEFGHIJ")
    assert raw.sdo(5, [0x40, 0x01, 0x20, 0x00]) == bytes([0x41, 0x01, 0x20, 0x00, 10, 0, 0, 0])
    assert raw.sdo(5, [0x60]) == b"\x00ABCDEFG"
    assert raw.sdo(5, [0x70]) == bytes([0x10 | (4 << 1) | 1]) + b"HIJ" + bytes(4)
    assert node.sdo.state.name == "IDLE"
