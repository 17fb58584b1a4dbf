"""Kernel-timestamped captures of EtherCAT frames on one interface, and the request/reply pairs they hold.

Where a frame waited is measured where it happens: a capture on the emulator's veth end sees each request
when the kernel delivered it (before it queued for the wire thread: the interpreter lock, a CPU, a stall
all count) and each reply when the emulator sent it, so reply - request is the emulator's residence
time; a capture on the master's end gives the round trip as the master lives it (replies after its
timeout are its late replies). Timestamps are the kernel's (``SO_TIMESTAMPNS``, CLOCK_REALTIME, the same
in every namespace), so how late the capturing process reads a frame does not matter.

:class:`Capture` runs ``python -m benchmarks.capture IFACE FILE`` (inside a namespace with ``prefix``)
until stopped; the file holds one :data:`RECORD` per frame. :func:`pairs` matches replies to requests:
a segment and a veth pair answer in order (one wire thread, FIFO queues), so each reply is the waiting
request whose key it carries and the requests it skips were never answered. That is exact only where
the key of every waiting request is unique, so the benchmarks' cyclic masters write :func:`cycle_tag`
(their cycle number) into the first output bytes of each LRW (docstring of :func:`pairs`).
"""

from __future__ import annotations

import os
import signal
import socket
import struct
import subprocess
import sys
from array import array
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["RECORD", "Capture", "Pair", "Record", "Tail", "cycle_tag", "explain_late", "frame_key", "pairs",
           "read_records", "tail_of"]

ETH_P_ALL = 0x0003
ETHERCAT_TYPE = b"\x88\xa4"
PACKET_OUTGOING = 4
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
#: time (ns), sent by this interface (1) or received (0), the frame's key (:func:`frame_key`)
RECORD = struct.Struct("<qB16s")
#: the bytes of a key that no slave changes (the datagram header's); the rest is a sample of the data
HEADER = 8
_TIMESPEC = struct.Struct("@qq")
#: how many requests wait for a reply at most (older ones count as never answered)
MAX_SKIP = 1024
#: bytes of :func:`cycle_tag` that carry the cycle number (little-endian)
TAG = struct.Struct("<I")


@dataclass(frozen=True)
class Pair:
    """A request and its reply (None: never answered), kernel times in ns; ``ambiguous``: another request
    with what the reply carries (the same key, or for a read the same header) was waiting too, so the
    reply's age is a guess (the oldest such request's), not a measurement."""

    t_request: int
    t_reply: int | None
    key: bytes
    ambiguous: bool = False

    @property
    def delay_us(self) -> float | None:
        return None if self.t_reply is None else (self.t_reply - self.t_request) / 1000.0


#: one captured frame: kernel time (ns), whether this interface sent it, its datagram header key
Record = tuple[int, bool, bytes]


def frame_key(frame: bytes | bytearray | memoryview) -> bytes:
    """16 bytes of the first datagram: the fields no slave changes -- EtherCAT header (2), command, index
    (the frame index masters match on), offset address (2), length (2); the position address (ADP) is left
    out, auto-increment commands count it up on the way -- then its first 8 data bytes. Those come back
    unchanged in a write, and in an LRW whose image starts with outputs (SOEM maps the outputs of every
    slave before the inputs), which is where the benchmarks' masters put :func:`cycle_tag`."""
    return (bytes(frame[14:18]) + bytes(frame[20:24]) + bytes(frame[26:34])).ljust(16, b"\0")


def cycle_tag(cycle: int, size: int) -> bytes:
    """``size`` output bytes that carry ``cycle`` (its low 32 bits, little-endian, then zeros): a cyclic
    master writes them into the outputs of its first slave, an ``ethercat_io`` (digital u8 + two int16,
    any value valid), so the first data bytes of its LRW -- in the key -- differ every cycle and come
    back unchanged in the reply (an LRW carries the outputs as written; only the input areas are
    filled in on the way, ETG.1000.4 logical addressing), whatever state the slaves are in."""
    return TAG.pack(cycle & 0xFFFFFFFF).ljust(size, b"\0")[:size]


def pairs(records: Iterable[Record], requests_outgoing: bool) -> Iterator[Pair]:
    """Requests (frames in the ``requests_outgoing`` direction) paired with their replies, in request order,
    streamed (a capture of hours never sits in memory).

    A segment and a veth pair answer in order, so a reply belongs to one waiting request and every request
    before that one was never answered. Which one: the waiting request with the reply's whole key (a write,
    a cyclic LRW), else the first with its datagram header (a read: its data changes on the way); a reply
    matching no waiting request (another party's) is ignored.

    Why the data and not the frame index: the index is in the key, but a master reuses it (SOEM has 16),
    and SOEM's outputs repeat: the ECAN-Lite's stream publishes the same image again after a lost cycle,
    and after a stall every slave is in SAFEOP and the image is constant. Then dozens of requests of one
    index wait with one key, and a fresh reply would be taken by the oldest of them (the bench once
    counted 1191 "stale replies" after a 200 ms stall where the master's own check saw none). The cycle
    number (:func:`cycle_tag`) makes every cyclic request's key unique, so its reply pairs with exactly
    it and its age is its own. Where requests still share a key (a master that writes no tag, a read
    polled while another waits) the pair is marked ``ambiguous`` rather than trusted."""
    waiting: deque[tuple[int, bytes]] = deque()
    for t, outgoing, key in records:
        if outgoing == requests_outgoing:
            waiting.append((t, key))
            if len(waiting) > MAX_SKIP:     # nothing answers that far back any more
                t0, k0 = waiting.popleft()
                yield Pair(t0, None, k0)
            continue
        header = key[:HEADER]
        first = exact = -1
        for i, (_t_req, k_req) in enumerate(waiting):
            if k_req == key:
                exact = i
                break
            if first < 0 and k_req[:HEADER] == header:
                first = i
        found = exact if exact >= 0 else first
        if found < 0:
            continue
        for _ in range(found):
            t0, k0 = waiting.popleft()
            yield Pair(t0, None, k0)
        t_req, k_req = waiting.popleft()
        twin = k_req if exact >= 0 else None
        ambiguous = any((k == twin) if twin is not None else (k[:HEADER] == header) for _t, k in waiting)
        yield Pair(t_req, t, k_req, ambiguous)
    for t0, k0 in waiting:
        yield Pair(t0, None, k0)


def read_records(path: str | Path) -> Iterator[Record]:
    """The records of a capture file, streamed."""
    with open(path, "rb") as f:
        while chunk := f.read(RECORD.size * 4096):
            usable = len(chunk) - len(chunk) % RECORD.size
            for t, o, k in RECORD.iter_unpack(chunk[:usable]):
                yield t, bool(o), k


@dataclass
class Tail:
    """What a run of pairs showed: requests, unanswered ones, delays over each limit, and (``keep``) every
    delay for percentiles."""

    limits_us: tuple[float, ...] = ()
    keep: bool = True
    requests: int = 0
    unanswered: int = 0
    #: answered pairs whose request was not the only one waiting with that key (:attr:`Pair.ambiguous`)
    ambiguous: int = 0
    over: dict[float, int] = field(default_factory=dict)
    worst_us: float = 0.0
    #: 8 bytes a delay: an hour at 1 kHz is 29 MB
    delays_us: array[float] = field(default_factory=lambda: array("d"))

    def add(self, p: Pair) -> None:
        self.requests += 1
        d = p.delay_us
        if d is None:
            self.unanswered += 1
            return
        self.ambiguous += p.ambiguous
        self.worst_us = max(self.worst_us, d)
        for limit in set(self.limits_us):     # one count per limit, however often it is given
            if d > limit:
                self.over[limit] = self.over.get(limit, 0) + 1
        if self.keep:
            self.delays_us.append(d)

    def percentiles(self) -> dict[str, float]:
        """p50 / p99 / p99.9 / max in us (NaN without kept delays)."""
        s = sorted(self.delays_us)
        nan = float("nan")

        def q(x: float) -> float:
            return s[min(len(s) - 1, int(x * len(s)))] if s else nan
        return {"p50_us": q(0.5), "p99_us": q(0.99), "p999_us": q(0.999), "max_us": s[-1] if s else nan}


def tail_of(path: str | Path, requests_outgoing: bool, limits_us: tuple[float, ...] = (), keep: bool = True,
            t0_ns: int = 0, t1_ns: int | None = None) -> Tail:
    """The :class:`Tail` of a capture file's pairs whose request lies in [t0_ns, t1_ns)."""
    tail = Tail(limits_us, keep)
    for p in pairs(read_records(path), requests_outgoing):
        if p.t_request >= t0_ns and (t1_ns is None or p.t_request < t1_ns):
            tail.add(p)
    return tail


def explain_late(master: str | Path, emulator: str | Path | None, limit_us: float, t0_ns: int, t1_ns: int,
                 origin_ns: int, most: int = 5) -> list[str]:
    """Up to ``most`` replies of the master's capture older than ``limit_us`` whose request lies in [t0_ns,
    t1_ns), each with where it waited: the same frame on the emulator's end (its capture, same key, the
    first seen after the master sent it) came in and left when -- a residence over the limit is the rig's
    doing, a short one the VM's. Times in ms from ``origin_ns`` (a stall's start)."""
    late = [p for p in pairs(read_records(master), True)
            if t0_ns <= p.t_request < t1_ns and p.delay_us is not None and p.delay_us > limit_us][:most]
    seen: dict[Pair, Pair] = {}
    if emulator is not None and late:
        for e in pairs(read_records(emulator), False):
            for p in late:
                if p not in seen and e.key == p.key and p.t_request <= e.t_request < p.t_request + 50_000_000:
                    seen[p] = e

    def ms(t: int) -> str:
        return f"{(t - origin_ns) / 1e6:+.1f} ms"
    out = []
    for p in late:
        line = f"reply older than {limit_us / 1000:g} ms: request sent at {ms(p.t_request)}, answered after " \
               f"{(p.delay_us or 0.0) / 1000:.1f} ms"
        there = seen.get(p)
        if there is not None and there.t_reply is not None:
            held = (there.delay_us or 0.0) > limit_us
            line += f"; on the emulator's end in at {ms(there.t_request)}, out at {ms(there.t_reply)} (residence " \
                    f"{(there.delay_us or 0.0) / 1000:.1f} ms: {'the rig held it' if held else 'the VM delayed it'})"
        elif emulator is not None:
            line += "; not found answered on the emulator's end"
        out.append(line)
    return out


def _stamp(ancdata: list[tuple[int, int, bytes]]) -> int:
    for level, kind, payload in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(payload)
            return int(sec * 1_000_000_000 + nsec)
    return 0


def record_frames(iface: str, path: str) -> None:
    """Capture until SIGTERM/SIGINT, one record per EtherCAT frame of ``iface`` (prints 'ready' once bound)."""
    stop = [False]

    def finish(signum: int, frame: object) -> None:
        stop[0] = True

    signal.signal(signal.SIGTERM, finish)
    signal.signal(signal.SIGINT, finish)
    # every protocol: the kernel shows a packet socket the frames its interface sends only then
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    sock.bind((iface, ETH_P_ALL))
    sock.settimeout(0.2)
    with open(path, "wb") as out:
        print("ready", flush=True)
        while not stop[0]:
            try:
                frame, ancdata, _flags, addr = sock.recvmsg(64, 64)
            except (TimeoutError, InterruptedError):
                continue
            if len(frame) < 24 or frame[12:14] != ETHERCAT_TYPE:
                continue
            out.write(RECORD.pack(_stamp(ancdata), int(addr[2] == PACKET_OUTGOING), frame_key(frame)))
    sock.close()


class Capture:
    """``record_frames`` in a child process (inside a namespace with ``prefix``), started once bound."""

    def __init__(self, iface: str, path: str | Path, prefix: Sequence[str] = ()) -> None:
        self.path = Path(path)
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)}
        self.proc = subprocess.Popen([*prefix, sys.executable, "-m", "benchmarks.capture", iface, str(path)],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=root, env=env)
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "ready":
            _, err = self.proc.communicate(timeout=5)
            raise RuntimeError(f"the capture on {iface} did not start: {err.strip()[-500:]}")

    def stop(self) -> Path:
        """End the capture; its file (:func:`read_records`, :func:`tail_of`)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
        return self.path

    def __enter__(self) -> Capture:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


if __name__ == "__main__":
    record_frames(sys.argv[1], sys.argv[2])
