"""The Modbus gateway as a user runs it (`gatewaylab run`) against what clients really send: garbage,
floods and unserved unit ids (issue 21 defect 6; docs/devices/modbus_gateway.md "Exceptions").

Bad requests (random bytes, truncated MBAP headers, wrong lengths, a bad protocol id, undecodable
PDUs, a connection closed mid-request) cost at most one line each on the rig's stderr, no
traceback and no hex dump, at most ``LOG_BURST`` lines per ``LOG_WINDOW`` s under a flood, and the
server answers pymodbus's own client afterwards. A unit id the gateway does not serve answers 0x0A
whatever the address and count (Modbus Application Protocol V1.1b3 section 7: 0x0A "Gateway Path
Unavailable"; the gateway checks the path before it forwards anything).
"""

from __future__ import annotations

import math
import random
import re
import socket
import struct
import time
from collections.abc import Iterator

import pytest
from pymodbus.client import ModbusTcpClient

from gatewaylab.devices.modbus_gateway.server import LOG_BURST, LOG_WINDOW
from gatewaylab.rig.process import RigProcess

WAIT = 20.0

#: drive 2 on can0 and a gateway serving it (unit 2), its TCP port chosen by the rig
RIG = """
bus = [{ name = "can0" }]
drive = [{ bus = "can0", node_id = 2, serial = 0x1002 }]
device = [{ kind = "modbus_gateway", name = "mb1", bus = "can0", node_id = 100, nodes = [2] }]
"""

#: what pymodbus writes when it dumps frames ("0x0 0x1 0x0 ...") or a traceback
HEX_DUMP = re.compile(r"(0x[0-9a-f]{1,2} ){3}")


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    tmp = tmp_path_factory.mktemp("userpath-modbus")
    rig_file = tmp / "modbus.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, workdir=tmp, timeout=60) as r:
        yield r


def _port(rig: RigProcess) -> int:
    endpoint = rig.info["modbus"]["mb1"]
    assert isinstance(endpoint, str) and endpoint.startswith("tcp:127.0.0.1:")
    return int(endpoint.rsplit(":", 1)[1])


def _mbap(tid: int, pdu: bytes, unit: int = 2, pid: int = 0, length: int | None = None) -> bytes:
    """Modbus TCP ADU: MBAP header (transaction, protocol id, length = unit + PDU, unit) + PDU."""
    return struct.pack(">HHHB", tid, pid, len(pdu) + 1 if length is None else length, unit) + pdu


def _send_and_finish(port: int, data: bytes, abrupt: bool = False) -> bytes:
    """Send ``data`` on a connection of its own, then end it: a half close (shutdown) and read what
    the server answers until it closes too, so the server has handled every byte when this
    returns; ``abrupt``: close without waiting (a client that vanishes mid-request)."""
    answer = b""
    with socket.create_connection(("127.0.0.1", port), timeout=WAIT) as sock:
        sock.sendall(data)
        if abrupt:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))   # RST
            return answer
        sock.shutdown(socket.SHUT_WR)
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            chunk = sock.recv(4096)
            if not chunk:
                break
            answer += chunk
    return answer


def _served(port: int) -> None:
    """pymodbus's own client reads the statusword of node 2 (input register 0): the server serves."""
    with ModbusTcpClient("127.0.0.1", port=port, timeout=5) as client:
        r = client.read_input_registers(0, count=1, device_id=2)
        assert not r.isError(), r


def _new_lines(rig: RigProcess, offset: int) -> list[str]:
    return [line for line in rig.log_text()[offset:].splitlines() if line.strip()]


def _check_clean(lines: list[str]) -> None:
    text = "\n".join(lines)
    assert "Traceback" not in text and "File \"" not in text, text
    assert ">>>>>" not in text and not HEX_DUMP.search(text), text


def test_each_bad_request_costs_at_most_one_line_and_the_server_still_serves(rig: RigProcess) -> None:
    """Issue 21 defect 6: 'One log line per bad request'; no pymodbus traceback or per-byte dump
    reaches the rig's stderr, and pymodbus's client is served afterwards."""
    port = _port(rig)
    _served(port)
    offset = len(rig.log_text())
    rnd = random.Random(21)
    bad: list[tuple[bytes, bool]] = []
    bad += [(rnd.randbytes(rnd.randrange(8, 300)), False) for _ in range(6)]         # random bytes
    bad += [(b"\x00\x01\x00", False), (b"\x00\x01\x00\x00\x00", False)]             # truncated MBAP headers
    bad += [(_mbap(1, b"\x03\x00\x00\x00\x01", pid=0x1234), False)]                 # protocol id not 0
    bad += [(_mbap(2, b"\x03\x00\x00\x00\x01", length=0xFF), False)]                # length longer than sent
    bad += [(_mbap(3, b"\x03\x00", length=2), False)]                               # length shorter than the PDU
    bad += [(_mbap(4, b"\x03\x00\x00\x00\x01", length=1), False)]                   # length: no function code
    bad += [(_mbap(5, b"\x63\x00\x00"), False)]                                     # unknown function code
    bad += [(_mbap(6, b"\x03\x00\x00\x00\x00"), False)]                             # FC 3 with count 0
    bad += [(_mbap(7, b"\x10\x00\x00\x00\x02\x09\x00\x01\x00\x02"), False)]         # FC 16 byte count wrong
    bad += [(_mbap(8, b"\x08\x12\x34\x00\x00"), False)]                             # FC 8 unknown sub-function
    bad += [(_mbap(9, b"\x03\x00\x00\x00\x01")[:9], True)]                          # closed mid-request
    bad += [(_mbap(10, b"\x10\x00\x00\x00\x02\x04\x00\x01")[:12], True)]            # closed mid-request
    for data, abrupt in bad:
        _send_and_finish(port, data, abrupt)
    _served(port)
    lines = _new_lines(rig, offset)
    _check_clean(lines)
    assert len(lines) <= len(bad), lines


def test_a_flood_of_bad_requests_is_rate_limited(rig: RigProcess) -> None:
    """Issue 21 defect 6: 'a client can flood the log' -- rate-limited: at most LOG_BURST lines per
    LOG_WINDOW s (plus one line per window counting the rest), however many bad requests come."""
    port = _port(rig)
    offset = len(rig.log_text())
    unknown = [fc for fc in range(0x41, 0x7F) if fc not in (0x41, 0x42, 0x43, 0x5A, 0x5B, 0x64)]
    count = 400
    start = time.monotonic()
    with socket.create_connection(("127.0.0.1", port), timeout=WAIT) as sock:
        for n in range(count):
            fc = unknown[n % len(unknown)]     # consecutive requests differ (no 'Repeating' folding)
            sock.sendall(_mbap(n + 1, bytes([fc, n & 0xFF, 0, 0])))
            answer = sock.recv(260)
            # an exception response 01 illegal function (pymodbus cannot name a function it does not know)
            assert answer[:2] == (n + 1).to_bytes(2, "big") and answer[7] & 0x80 and answer[8] == 0x01, answer.hex()
    elapsed = time.monotonic() - start
    _served(port)
    lines = _new_lines(rig, offset)
    _check_clean(lines)
    windows = math.ceil(elapsed / LOG_WINDOW) + 1
    assert len(lines) <= windows * (LOG_BURST + 1), (len(lines), elapsed, lines[:20])


def test_an_unserved_unit_answers_0x0A_whatever_the_address_and_count(rig: RigProcess) -> None:
    """Modbus Application Protocol V1.1b3 section 7 / docs/devices/modbus_gateway.md: a unit id the
    gateway does not serve is 0x0A gateway path unavailable -- checked before the address and the
    count (a gateway decides the path first); a served unit still gets 02 for unmapped registers."""
    with ModbusTcpClient("127.0.0.1", port=_port(rig), timeout=5) as client:
        for r in (client.read_holding_registers(0, count=10, device_id=7),
                  client.read_input_registers(100, count=10, device_id=7),
                  client.write_registers(0, [0] * 10, device_id=7),
                  client.read_coils(0, count=10, device_id=7),
                  client.read_holding_registers(65530, count=6, device_id=9),
                  client.read_holding_registers(0, count=1, device_id=7)):
            assert r.isError() and r.exception_code == 0x0A, r
        r = client.read_holding_registers(0, count=10, device_id=2)       # registers 8 and 9 are not mapped
        assert r.isError() and r.exception_code == 0x02, r
        r = client.read_holding_registers(0, count=8, device_id=2)        # the whole default map
        assert not r.isError(), r


def test_garbage_leaves_no_traceback_in_the_whole_log(rig: RigProcess) -> None:
    """Everything this module sent, from the rig's point of view: not one traceback or dump line."""
    _check_clean(rig.log_text().splitlines())
