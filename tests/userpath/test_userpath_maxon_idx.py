"""The maxon IDX of a running rig through pyserial, as a user's program talks to it (issue 21, "The user's path
as a suite"; docs/devices/maxon_idx.md): the ready file's ``usb.idx1.pty`` opened with ``serial.Serial`` and
its ``usb.idx1.tcp`` with ``serial.serial_for_url("socket://...")``; requests built here the way the IDX
Communication Guide teaches (2.2.3 CRC, 2.2.4 byte stuffing; checked against the guide's 2.2.8 example
bytes), not with gatewaylab's codec. ReadObject / WriteObject (local and through the SDO gateway), garbage
then a valid request, a client that closes mid-frame. Latency: the first answer after opening the port
(< 1 s) and the steady state (p99 of ReadObject round trips).
"""

from __future__ import annotations

import binascii
import random
import time
from collections.abc import Callable, Iterator

import pytest
import serial
from userpath_kit import Latencies, bound, measured

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"

[[bus]]
name = "can0"
bitrate = 1000000

[[device]]
kind = "maxon_idx"
name = "idx1"
bus = "can0"
node_id = 1
serial = 0x2001
usb = { pty = true, tcp_port = 0 }

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
"""

DLE, STX = 0x90, 0x02
#: guide 2.2.8: ReadObject "Home Position" 0x30B0:00 of node 1, and its answer with 0x30B0 = 36865
GUIDE_REQUEST = bytes.fromhex("90 02 60 02 01 B0 30 00 2E 62")
GUIDE_ANSWER = bytes.fromhex("90 02 00 04 00 00 00 00 01 90 90 00 00 9A 5C")
TIMEOUT = 5.0


# -- the guide's framing, as a user's program writes it -------------------------------------------------
def idx_frame(opcode: int, payload: bytes) -> bytes:
    """Guide 2.2: OpCode, Len (words), payload, CRC-CCITT over the words, all low byte first on the wire,
    every DLE after the sync doubled, DLE STX in front. The guide's CalcFieldCRC over the words with a zero
    CRC word is XMODEM (``crc_hqx``) over the words' bytes high byte first (shared/notes/maxon-usb-protocol)."""
    body = bytes((opcode, len(payload) // 2)) + payload
    crc = binascii.crc_hqx(bytes(b for i in range(0, len(body), 2) for b in (body[i + 1], body[i])), 0)
    frame = body + crc.to_bytes(2, "little")
    return bytes((DLE, STX)) + frame.replace(bytes((DLE,)), bytes((DLE, DLE)))


def read_object(node: int, index: int, sub: int) -> bytes:
    """Guide 2.1.1.1 ReadObject (0x60, Len 2)."""
    return idx_frame(0x60, bytes((node,)) + index.to_bytes(2, "little") + bytes((sub,)))


def write_object(node: int, index: int, sub: int, value: int) -> bytes:
    """Guide 2.1.2.1 WriteObject (0x68, Len 4): 4 data bytes."""
    return idx_frame(0x68, bytes((node,)) + index.to_bytes(2, "little") + bytes((sub,))
                     + value.to_bytes(4, "little", signed=value < 0))


def read_answer(port: serial.SerialBase) -> tuple[bytes, bytes]:
    """One answer frame: (its bytes on the wire, the unstuffed OpCode..CRC). Skips bytes before DLE STX."""
    raw = bytearray()
    deadline = time.monotonic() + TIMEOUT

    def byte() -> int:
        while True:
            b = port.read(1)
            if b:
                raw.extend(b)
                return b[0]
            assert time.monotonic() < deadline, f"no answer frame, got {bytes(raw).hex(' ')}"

    while True:   # sync
        if byte() == DLE and byte() == STX:
            break
    start = len(raw) - 2
    frame = bytearray()
    need = 2
    while len(frame) < need:
        b = byte()
        if b == DLE:
            assert byte() == DLE, "unstuffed DLE inside a frame"
        frame.append(b)
        if len(frame) == 2:
            need = 2 + frame[1] * 2 + 2
    return bytes(raw[start:]), bytes(frame)


def error_code(frame: bytes) -> int:
    """The answer's Communication Error Code (guide 2.1: the first DWORD of every answer)."""
    assert frame[0] == 0x00, f"answer OpCode 0x{frame[0]:02X}"
    return int.from_bytes(frame[2:6], "little")


def ask(port: serial.SerialBase, request: bytes) -> tuple[bytes, bytes]:
    port.write(request)
    port.flush()
    return read_answer(port)


# -- fixtures ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def rig(start_rig: Callable[..., RigProcess]) -> RigProcess:
    return start_rig(RIG)


def open_port(rig: RigProcess, kind: str) -> serial.SerialBase:
    """pyserial on the ready file's endpoint: the pty path, or the TCP endpoint as a socket:// URL."""
    where = str(rig.info["usb"]["idx1"][kind])
    if kind == "pty":
        return serial.Serial(where, baudrate=115200, timeout=0.05)
    host_port = where.removeprefix("tcp:")
    return serial.serial_for_url(f"socket://{host_port}", timeout=0.05)


@pytest.fixture(params=["pty", "tcp"])
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def port(rig: RigProcess, kind: str) -> Iterator[serial.SerialBase]:
    p = open_port(rig, kind)
    try:
        yield p
    finally:
        p.close()


# -- tests ------------------------------------------------------------------------------------------------
def test_framing_here_reproduces_the_guide_example() -> None:
    """Guide 2.2.8 steps 1-8: ReadObject 0x30B0:00 of node 1 is 90 02 60 02 01 B0 30 00 2E 62 (CRC 0x622E)."""
    assert read_object(1, 0x30B0, 0) == GUIDE_REQUEST


@measured
def test_write_then_guide_read_object_golden_bytes_first_and_steady(rig: RigProcess, kind: str) -> None:
    """Guide 2.1.2.1 WriteObject 0x30B0 = 36865, then 2.2.8's ReadObject: the answer is the guide's bytes
    exactly (0x00009001, the DLE in it stuffed). Latency: the first answer after opening the port, then
    ReadObject round trips."""
    opened = time.time()
    with open_port(rig, kind) as port:
        wire, frame = ask(port, write_object(1, 0x30B0, 0, 36865))
        lat = Latencies(f"IDX ReadObject over {kind}")
        lat.first = time.time() - opened
        assert frame[1] == 2 and error_code(frame) == 0, wire.hex(" ")
        for _ in range(200):
            asked = time.time()
            wire, _ = ask(port, GUIDE_REQUEST)
            lat.add(time.time() - asked)
            assert wire == GUIDE_ANSWER, wire.hex(" ")
    lat.check()


def test_gateway_read_and_write_of_another_node(port: serial.SerialBase) -> None:
    """Guide chapter 5: a node id other than the IDX's own goes to that node by SDO: drive 2's serial number
    0x1018:04, and a WriteObject of its profile velocity 0x6081 read back; a node that is not there answers
    0x05040000 (SDO timeout)."""
    _, frame = ask(port, read_object(2, 0x1018, 4))
    assert error_code(frame) == 0 and int.from_bytes(frame[6:10], "little") == 0x1002
    _, frame = ask(port, write_object(2, 0x6081, 0, 5000))
    assert error_code(frame) == 0
    _, frame = ask(port, read_object(2, 0x6081, 0))
    assert error_code(frame) == 0 and int.from_bytes(frame[6:10], "little") == 5000
    _, frame = ask(port, read_object(9, 0x1000, 0))
    assert error_code(frame) == 0x05040000


def test_garbage_then_a_valid_request_is_answered(port: serial.SerialBase) -> None:
    """Guide 2.2 (framing, resync on DLE STX) and table 6-20: random bytes on the port, then a valid request:
    whatever the garbage made the IDX answer is an error answer, and the valid request gets its answer."""
    rnd = random.Random(21)
    port.write(rnd.randbytes(300) + bytes((DLE, STX, 0x60)))   # ends inside a frame's header
    port.write(GUIDE_REQUEST)
    port.flush()
    others = []
    while True:
        wire, frame = read_answer(port)
        if wire == GUIDE_ANSWER:
            break
        others.append(frame)
        assert error_code(frame) != 0, wire.hex(" ")
        assert len(others) < 50
    _, frame = ask(port, read_object(2, 0x1018, 4))          # and the port works on
    assert error_code(frame) == 0 and int.from_bytes(frame[6:10], "little") == 0x1002


@measured
def test_client_closing_mid_frame_then_the_next_client_is_answered(rig: RigProcess, kind: str) -> None:
    """A program that dies after writing half a request (its port closed mid-frame): the next program that
    opens the port gets its first answer at once (the partial frame is dropped at the next DLE STX, guide
    2.2.4; or with the connection, on TCP)."""
    with open_port(rig, kind) as port:
        port.write(GUIDE_REQUEST[:5])
        port.flush()
    opened = time.time()
    with open_port(rig, kind) as port:
        wire, _ = ask(port, GUIDE_REQUEST)
        first = time.time() - opened
    assert wire == GUIDE_ANSWER, wire.hex(" ")
    print(f"\nIDX over {kind}: first answer after a client closed mid-frame {first * 1e3:.1f} ms")
    bound(first, 1.0, f"IDX over {kind}: first answer after a client closed mid-frame")
