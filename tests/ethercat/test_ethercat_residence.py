"""Replies on time or not at all: a frame that waited in the emulator longer than a real line could hold it
is dropped, counted and logged once per burst, never answered late (docs/rig.md ``[ethercat]
max_residence_ms``, docs/decisions.md).

ETG.1000.4 (data link layer): a frame passes each slave on the fly and returns to the master within the line's
propagation delay; a master whose frame is not back within its receive timeout (SOEM ``EC_TIMEOUTRET``
2000 us, KickCAT's link timeout 2 ms) counts it lost and reuses its index. The age decision is a pure
function of timestamps (gatewaylab/ethercat/residence.py), tested here with numbers; the wire applies it
with an injected clock (its ``now_ns``), so a frame is made old without waiting.
"""

from __future__ import annotations

import json
import logging
import struct
import subprocess
import sys
import threading
import time
from typing import Any, cast

import pytest

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.residence import (
    SCM_TIMESTAMPNS,
    SOL_SOCKET,
    LateBurst,
    LateDrops,
    is_late,
    kernel_timestamp_ns,
    residence_limit_ns,
)
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport
from gatewaylab.ethercat.wire_pcap import PcapWriter

MS = 1_000_000


# ------------------------------------------------------------------------------------------ the pure decision
def test_age_within_the_limit_is_answered_beyond_it_dropped() -> None:
    """The age counts from the receive timestamp to now; exactly the limit is still in time."""
    limit = residence_limit_ns(2.0)
    assert limit == 2 * MS
    t0 = 1_700_000_000 * 1_000_000_000
    assert not is_late(t0, t0, limit)
    assert not is_late(t0, t0 + limit, limit)
    assert is_late(t0, t0 + limit + 1, limit)
    assert is_late(t0, t0 + 117 * MS, limit)     # the 200 ms kill -STOP of the issue: 117 ms late replies


def test_no_limit_and_clock_steps() -> None:
    """``max_residence_ms = 0`` never drops; a receive stamp after now (the wall clock stepped back) is age 0."""
    assert residence_limit_ns(0) == 0 and residence_limit_ns(-1.0) == 0
    assert not is_late(0, 10**18, 0)
    assert not is_late(5 * MS, 0, 2 * MS)


def test_kernel_timestamp_from_ancillary_data() -> None:
    """socket(7) SO_TIMESTAMPNS: an SCM_TIMESTAMPNS control message holding a struct timespec."""
    stamp = struct.pack("@qq", 1_700_000_000, 123_456_789)
    assert kernel_timestamp_ns([(SOL_SOCKET, SCM_TIMESTAMPNS, stamp)]) == 1_700_000_000_123_456_789
    assert kernel_timestamp_ns([(0, 8, b"\0" * 16)]) is None            # PACKET_AUXDATA or another: ignored
    assert kernel_timestamp_ns([(SOL_SOCKET, SCM_TIMESTAMPNS, b"\0" * 4)]) is None   # truncated
    assert kernel_timestamp_ns([]) is None


def test_one_report_per_burst_with_count_and_oldest_age() -> None:
    """A burst (frames dropped until one is answered or the line is idle) gives one report: how many frames,
    the oldest age; bursts closer than a second to the last report are merged into the next one."""
    drops = LateDrops(report_every_ns=1000 * MS)
    assert drops.settle(0) is None and not drops.pending
    for age in (117, 90, 3):
        drops.drop(age * MS)
    assert drops.settle(10 * MS) == LateBurst(3, 117 * MS)
    assert drops.settle(11 * MS) is None                  # reported once
    drops.drop(5 * MS)                                    # a new burst 0.1 s later: merged
    assert drops.settle(110 * MS) is None and drops.pending
    assert drops.report_due_in_ns(110 * MS) == 900 * MS
    drops.drop(7 * MS)
    assert drops.settle(1010 * MS) == LateBurst(2, 7 * MS)
    assert drops.total == 5
    drops.drop(4 * MS)
    assert drops.flush(1011 * MS) == LateBurst(1, 4 * MS)   # stop(): whatever pends, at once
    assert "dropped 1 frame(s) older than 2 ms" in LateBurst(1, 4 * MS).describe(2 * MS)


# ------------------------------------------------------------------------------------------ the wire
#: From the master's end of the pair: COUNT frames back to back, each one BRD of register 0x0000 with its own
#: index; prints "sent", then the indices whose replies came back (collected until 1 s of silence).
MASTER = """
import json, select, socket, struct, sys
sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x88A4))
sock.bind((sys.argv[1], 0x88A4))
first, count = int(sys.argv[2]), int(sys.argv[3])
for index in range(first, first + count):
    datagram = struct.pack("<BBHHHH", 7, index, 0, 0, 2, 0) + bytes(2) + bytes(2)
    sock.send(b"\\xff" * 6 + b"\\x02\\0\\0\\0\\0\\x01" + struct.pack("!H", 0x88A4)
              + struct.pack("<H", len(datagram) | 0x1000) + datagram)
print("sent", flush=True)
got = []
while len(got) < count and select.select([sock], [], [], 1.0)[0]:
    frame, addr = sock.recvfrom(2048)
    if addr[2] != socket.PACKET_OUTGOING and frame[12:14] == b"\\x88\\xa4" and first <= frame[17] < first + count:
        got.append(frame[17])
print(json.dumps(got), flush=True)
"""


class _Clock:
    """Unix nanoseconds that run ``offset_ns`` ahead of the real ones (the kernel stamps stay real)."""

    def __init__(self) -> None:
        self.offset_ns = 0

    def __call__(self) -> int:
        return time.time_ns() + self.offset_ns


class _Stall:
    """A capture (written before a frame is processed) that, once armed, holds the wire thread inside the next
    frame until released: the frames sent meanwhile pile up in the socket, as behind a stalled emulator."""

    def __init__(self) -> None:
        self.armed = False
        self.arrived = threading.Event()
        self.release = threading.Event()

    def write(self, t: float, frame: bytes | bytearray) -> None:
        if self.armed:
            self.armed = False
            self.arrived.set()
            self.release.wait(30)

    def close(self) -> None:
        """Nothing to close."""


def _exchange(veth_ns: Any, first: int, count: int, stall: _Stall | None = None) -> list[int]:
    """The master's frames ``first``.. (``count``); with ``stall`` the wire thread is held from the first of
    them until all are sent. The indices of the replies the master got."""
    proc = subprocess.Popen(["ip", "netns", "exec", veth_ns.namespace, sys.executable, "-c", MASTER,
                             veth_ns.master_iface, str(first), str(count)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    try:
        assert proc.stdout.readline().strip() == "sent"
        if stall is not None:
            assert stall.arrived.wait(30)
            stall.release.set()
        got: list[int] = json.loads(proc.stdout.readline())
    finally:
        if stall is not None:
            stall.release.set()
        proc.wait(60)
    return got


def test_the_wire_drops_frames_older_than_the_limit(veth_ns: Any, caplog: pytest.LogCaptureFixture) -> None:
    """Frames within ``max_residence_ms`` of their kernel receive stamp are answered; frames that look 10 s
    old (the wire's clock moved ahead, as after a stall) are not: the master gets no reply, the wire counts
    them in ``frames_dropped_late`` and logs the burst once (how many, the oldest age) when the line is
    idle again; answered frames do not count. The old wire answered every frame whatever its age.
    ``frames_late_on_arrival`` tells the frames the machine held (already late when the idle thread got them)
    from those that waited behind the emulator's own work."""
    clock = RealTimeClock()
    now = _Clock()
    stall = _Stall()
    # a limit far above any scheduling delay of this shared machine: only the 10 s jump makes frames late
    wire = WireTransport(Segment([create_io_slave(clock, "io")]), veth_ns.emulator_iface, clock, drive_clock=True,
                         max_residence_ms=5000.0, now_ns=now, pcap=cast(PcapWriter, stall))
    caplog.set_level(logging.WARNING, logger="gatewaylab.ethercat.wire")
    wire.start()
    try:
        assert wire.kernel_timestamps
        assert sorted(_exchange(veth_ns, 1, 3)) == [1, 2, 3]
        assert wire.frames_dropped_late == 0
        now.offset_ns = 10_000 * MS          # from now on every frame looks 10 s old
        stall.armed = True
        assert _exchange(veth_ns, 10, 4, stall) == []
        deadline = time.monotonic() + 30     # the line is idle: the burst is reported
        while not any("dropped" in r.getMessage() for r in caplog.records) and time.monotonic() < deadline:
            time.sleep(0.01)
        now.offset_ns = 0
        assert sorted(_exchange(veth_ns, 20, 2)) == [20, 21]
    finally:
        wire.stop()
    assert wire.frames_dropped_late == 4
    assert wire.stats()["frames_dropped_late"] == 4
    # the first came to an idle thread already "10 s old" (as after a stall of the machine); the other three
    # waited behind it in the socket while the emulator held the thread: the emulator's own lateness
    assert wire.stats()["frames_late_on_arrival"] == 1
    lines = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert len(lines) == 1, lines
    assert "dropped 4 frame(s) older than 5000 ms" in lines[0] and "(oldest 10" in lines[0], lines


class _Held:
    """A segment whose ``process`` holds the frame: ``blocked`` seconds without running (the process stopped
    by ``kill -STOP`` or a stalled VM, while the wire thread had the frame in hand), or ``busy`` seconds of
    its own work (a long state change in pure Python)."""

    def __init__(self, segment: Segment) -> None:
        self.segment = segment
        self.line_faults = None
        self.blocked = 0.0
        self.busy = 0.0

    def process(self, frame: bytearray, *, defer: bool = False) -> bool:
        if self.blocked:
            time.sleep(self.blocked)
        end = time.thread_time() + self.busy
        while time.thread_time() < end:
            pass
        return self.segment.process(frame, defer=defer)

    def after_frame(self) -> None:
        self.segment.after_frame()


def test_a_frame_held_while_the_emulator_stopped_is_dropped_its_own_work_is_not(veth_ns: Any) -> None:
    """Issue 31, the stall (benchmarks: a frame the wire thread had taken just before a 200 ms ``kill -STOP``
    was answered 208 ms late): the age is checked again before the reply is sent, less the thread's own CPU
    time on the frame. Held 100 ms without running (a stop): dropped and counted, never answered; 100 ms of its
    own work (a state change in pure Python): answered, as a master with a long timeout must still get it; over
    the limit with more than half the limit spent waiting: dropped."""
    clock = RealTimeClock()
    held = _Held(Segment([create_io_slave(clock, "io")]))
    wire = WireTransport(cast(Segment, held), veth_ns.emulator_iface, clock, drive_clock=True,
                         max_residence_ms=20.0)
    wire.start()
    try:
        assert sorted(_exchange(veth_ns, 1, 2)) == [1, 2]
        held.blocked = 0.1
        assert _exchange(veth_ns, 10, 1) == []
        assert wire.frames_dropped_late == 1 and wire.stats()["frames_late_on_arrival"] == 0
        held.blocked, held.busy = 0.0, 0.1
        assert _exchange(veth_ns, 20, 1) == [20]
        # held 15 ms (under the limit) and then 8 ms of work: 23 ms old, of which 15 ms waiting (over half the
        # limit): dropped (a master with SOEM's timeout of the limit would have seen a stale reply)
        held.blocked, held.busy = 0.015, 0.008
        assert _exchange(veth_ns, 30, 1) == []
    finally:
        wire.stop()
    assert wire.frames_dropped_late == 2
