"""The C echo of benchmarks/bench_ethercat.py (benchmarks/echo.c), the floor issue 23 compares paced
SOEM with: built with the package build's C compiler, it answers every EtherCAT frame unchanged over a
veth pair, as the bench's Python echo does. It runs inside a namespace the test creates; the test's raw
socket on the other end sends frames and compares what comes back byte for byte."""

from __future__ import annotations

import socket
import struct
import subprocess
import time
from pathlib import Path

import pytest
from wire_kit import net_capable, veth_namespace

from benchmarks.bench_ethercat import ETHERTYPE, PACKET_OUTGOING, build_c_echo

pytestmark = [pytest.mark.net]


def _frame(index: int) -> bytes:
    """ETG.1000.4 5.3: an EtherCAT frame (ethertype 0x88A4, header type 1) with one 32-byte LRW
    datagram whose index is ``index``, padded to 64 bytes with the working counter 0."""
    datagram = struct.pack("<BBIHHH", 12, index, 0x10000 * index, 32, 0, 0) + bytes(range(32)) + b"\0\0"
    return (b"\xff" * 6 + b"\x02\x00\x00\x00\x00\x01" + struct.pack("!H", ETHERTYPE)
            + struct.pack("<H", len(datagram) | 0x1000) + datagram)


def _answer(sock: socket.socket, timeout: float) -> bytes | None:
    """The next frame that came in (not one this socket sent), or None after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            data, addr = sock.recvfrom(2048)
        except TimeoutError:
            continue
        if addr[2] != PACKET_OUTGOING:
            return data
    return None


def test_c_echo_returns_every_frame_unchanged(tmp_path: Path) -> None:
    """Issue 23 ('paced SOEM p99 <= 2x the C echo's p99'): each EtherCAT frame (ETG.1000.4 5.3,
    ethertype 0x88A4) comes back once, byte for byte as sent (no slave processes it: the working
    counter stays 0); the echo ignores what it sent itself and counts what it echoed."""
    reason = net_capable()
    if reason is not None:
        pytest.skip(reason)
    program, why = build_c_echo(str(tmp_path))
    if program is None:
        pytest.skip(why)
    frames = [_frame(i) for i in range(1, 21)]
    with veth_namespace("gl-ech-", "ech") as (ns, emu, mst):
        echo = subprocess.Popen(["ip", "netns", "exec", ns, program, mst, "1"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            assert echo.stdout is not None
            assert echo.stdout.readline().strip() == "ready"
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETHERTYPE))
            sock.bind((emu, ETHERTYPE))
            sock.settimeout(0.05)
            try:
                answers = []
                for frame in frames:
                    sock.send(frame)
                    answers.append(_answer(sock, 5.0))
                late = _answer(sock, 0.2)           # nothing more: one answer per frame
            finally:
                sock.close()
        finally:
            echo.terminate()
            out, err = echo.communicate(timeout=10)
    assert answers == frames
    assert late is None
    assert out.strip() == f"echoed {len(frames)} failed 0", err
