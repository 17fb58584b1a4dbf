"""The line faults on the raw-socket wire (ethercat/wire.py + ethercat/line_faults.py): a raw master in the
test's namespace sends frames and lists the replies it gets, in order (docs/faults.md "EtherCAT faults").

ETG.1000.4: each frame carries its own datagram index, so a master tells which request a reply answers; a
duplicated reply arrives twice, a reordered one after the reply that followed it; a delayed reply arrives, in
order, once its delay has passed (no timing asserted: only that and in which order the replies come); a reply
held back is sent by the wire thread while the line is idle.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.line_faults import Kind, LineFault, LineFaults
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

#: sends BRDs of 0x0130 with indices 1..N, one after the other (each after the reply of the one before or
#: 50 ms; with a third argument back to back), then listens until 100 ms pass without a reply; prints the
#: indices of the replies in the order they came
MASTER = r'''
import json, select, socket, struct, sys
s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x88A4))
s.bind((sys.argv[1], 0x88A4))
got = []

def listen(seconds):
    while True:
        r, _, _ = select.select([s], [], [], seconds)
        if not r:
            return
        data, addr = s.recvfrom(2048)
        if addr[2] != 4 and len(data) > 17:
            got.append(data[17])
            return

burst = len(sys.argv) > 3
for idx in range(1, int(sys.argv[2]) + 1):
    dgram = struct.pack("<BBHHHH", 7, idx, 0, 0x130, 2, 0) + b"\0\0" + b"\0\0"
    frame = b"\xff" * 6 + b"\x02\0\0\0\0\x01" + b"\x88\xa4" + struct.pack("<H", len(dgram) | 0x1000) + dgram
    s.send(frame.ljust(60, b"\0"))
    if not burst:
        listen(0.05)
while True:
    before = len(got)
    listen(0.1)
    if len(got) == before:
        break
print(json.dumps(got))
'''


def _replies(veth_ns: Any, fault: LineFault, frames: int, burst: bool = False) -> tuple[list[int], WireTransport]:
    clock = RealTimeClock()
    segment = Segment([create_io_slave(clock, "io")])
    segment.line_faults = LineFaults()
    segment.line_faults.add(fault)
    # no age limit (max_residence_ms 0): these tests count the replies a line fault lets through, and on a loaded
    # machine the default limit may drop one as late (tests/ethercat/test_ethercat_residence.py covers that)
    wire = WireTransport(segment, veth_ns.emulator_iface, clock, drive_clock=True, realtime=False,
                         max_residence_ms=0)
    wire.start()
    try:
        out = subprocess.run(["ip", "netns", "exec", veth_ns.namespace, sys.executable, "-c", MASTER,
                              veth_ns.master_iface, str(frames), *(["burst"] if burst else [])],
                             capture_output=True, text=True, timeout=60)
    finally:
        wire.stop()
    assert out.returncode == 0, out.stderr
    got: list[int] = json.loads(out.stdout)
    return got, wire


def test_duplicate_sends_a_reply_twice(veth_ns: Any) -> None:
    """ec-duplicate 2: the first two replies come twice, the third once."""
    got, wire = _replies(veth_ns, LineFault(Kind.DUPLICATE, count=2), 3)
    assert got == [1, 1, 2, 2, 3] and wire.frames_out == 5


def test_reorder_sends_a_reply_after_the_next(veth_ns: Any) -> None:
    """ec-reorder 1 on frames in flight together: reply 1 waits for reply 2 and follows it (held up to 2 s
    here, so a stall of this machine cannot send it alone first); then 3 as usual."""
    got, _ = _replies(veth_ns, LineFault(Kind.REORDER, count=1, hold_s=2.0), 3, burst=True)
    assert got == [2, 1, 3]


def test_a_reordered_reply_goes_out_alone_after_its_hold(veth_ns: Any) -> None:
    """ec-reorder 1 while the master waits for each reply (50 ms): reply 1 leaves alone once its hold (5 ms)
    is over, sent by the idle wire thread; the master sees 1, 2, 3."""
    got, _ = _replies(veth_ns, LineFault(Kind.REORDER, count=1), 3)
    assert got == [1, 2, 3]


def test_delay_and_lose_on_the_wire(veth_ns: Any) -> None:
    """ec-delay 20 ms: every reply comes, in order, sent by the wire thread from its queue; ec-lose 2: the
    first two requests are never answered."""
    got, wire = _replies(veth_ns, LineFault(Kind.DELAY, delay_s=0.02), 3)
    assert got == [1, 2, 3] and wire.frames_out == 3
    got, wire = _replies(veth_ns, LineFault(Kind.LOSE, count=2), 4)
    assert got == [3, 4] and wire.frames_in >= 4
