"""String objects have a maximum length on the CANopen SDO server (the dictionary CoE shares).

CiA 301 7.2.4.3.3 (initiate download: the client may indicate the size; the server aborts what it
cannot take) and table 22 abort 0x06070012 "Data type does not match, length of service parameter
too high". The sample node's 0x2001 "String rw" declares 64 bytes (canopen_testkit).
"""

from __future__ import annotations

import struct

import canopen
import pytest
from canopen_testkit import remote_for

from gatewaylab.od import SdoAbortCode

TOO_HIGH = int(SdoAbortCode.LENGTH_TOO_HIGH)


def abort_code(answer: bytes | None) -> int:
    assert answer is not None, "the node stayed silent"
    assert answer[0] == 0x80, f"not an abort: {answer.hex()}"
    return int(struct.unpack_from("<I", answer, 4)[0])


def test_announced_size_above_the_maximum_is_aborted_at_initiate(make_node, raw) -> None:
    """A segmented download announcing 65 bytes into a 64-byte string is refused before any segment;
    64 bytes are taken."""
    node = make_node()
    assert abort_code(raw.sdo(5, [0x21, 0x01, 0x20, 0x00, 65, 0, 0, 0])) == TOO_HIGH
    assert abort_code(raw.sdo(5, [0x21, 0x01, 0x20, 0x00, 0x40, 0x42, 0x0F, 0])) == TOO_HIGH  # 1,000,000
    assert node.get(0x2001) == "gatewaylab CANopen node"
    assert raw.sdo(5, [0x21, 0x01, 0x20, 0x00, 64, 0, 0, 0]) == bytes([0x60, 0x01, 0x20, 0, 0, 0, 0, 0])


def test_unannounced_segmented_download_past_the_maximum_is_aborted(make_node, raw) -> None:
    """Without a size indication the server aborts with 0x06070012 once the data pass 64 bytes."""
    node = make_node()
    assert raw.sdo(5, [0x20, 0x01, 0x20, 0x00, 0, 0, 0, 0]) is not None
    toggle = 0
    for _ in range(9):  # 9 x 7 = 63 bytes
        assert raw.sdo(5, [toggle << 4, *b"abcdefg"]) == bytes([0x20 | toggle << 4]) + bytes(7)
        toggle ^= 1
    assert abort_code(raw.sdo(5, [toggle << 4, *b"hijklmn"])) == TOO_HIGH
    assert node.get(0x2001) == "gatewaylab CANopen node"


def test_block_download_announcing_too_much_is_aborted(make_node, raw) -> None:
    """CiA 301 7.2.4.3.9: block download initiate with size indication (s = 1) above the maximum."""
    make_node()
    assert abort_code(raw.sdo(5, [0xC2, 0x01, 0x20, 0x00, 65, 0, 0, 0])) == TOO_HIGH


def test_shorter_write_is_stored_as_written(make_node, network) -> None:
    """A shorter string is taken as it came (its length is the value's; docs/decisions.md)."""
    node = make_node()
    remote = remote_for(network, node)
    remote.sdo[0x2001].raw = "short"
    assert node.get(0x2001) == "short"
    assert remote.sdo[0x2001].raw == "short"
    remote.sdo[0x2001].raw = "x" * 64
    assert node.get(0x2001) == "x" * 64


def test_python_canopen_sees_the_length_abort(make_node, network) -> None:
    """python-canopen (the independent client) reports 0x06070012 for a 65-byte string."""
    node = make_node()
    remote = remote_for(network, node)
    with pytest.raises(canopen.SdoAbortedError) as err:
        remote.sdo[0x2001].raw = "y" * 65
    assert err.value.code == TOO_HIGH
    assert node.get(0x2001) == "gatewaylab CANopen node"
