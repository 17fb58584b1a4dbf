"""pcap capture of EtherCAT frames (link type 1, Ethernet), readable by Wireshark's EtherCAT dissector.

Timestamps are Unix time. The wire thread writes ``time.time()``; an in-process master writes its
clock time, so give the writer that clock (``PcapWriter(path, clock=clock)``): it adds the clock's
``wall_epoch`` (the Unix time of clock time 0, the one time base of traces, docs/rig.md).
"""

from __future__ import annotations

import struct
import threading
from typing import TYPE_CHECKING, BinaryIO

from gatewaylab.ethercat.errors import PcapFormatError

if TYPE_CHECKING:
    from gatewaylab.common.clock import Clock

__all__ = ["LINKTYPE_ETHERNET", "PCAP_GLOBAL", "PCAP_MAGIC", "PCAP_RECORD", "PcapWriter", "read_pcap"]


PCAP_GLOBAL = struct.Struct("<IHHiIII")
PCAP_RECORD = struct.Struct("<IIII")
LINKTYPE_ETHERNET = 1
PCAP_MAGIC = 0xA1B2C3D4


class PcapWriter:
    """Appends frames with their timestamps; safe to call from the wire thread and others.

    ``write(t, frame)`` records ``epoch + t``: ``epoch`` is 0 for Unix timestamps (the wire thread),
    or ``clock.wall_epoch`` with ``clock`` given, for clock times (in-process masters). The file is
    flushed at least every ``flush_period`` of timestamps, so a killed process leaves a readable capture.
    """

    def __init__(self, out: BinaryIO | str, snaplen: int = 65535, *, clock: Clock | None = None,
                 epoch: float | None = None, flush_period: float = 0.1) -> None:
        self.epoch = epoch if epoch is not None else (clock.wall_epoch if clock is not None else 0.0)
        self.flush_period = flush_period
        self._flushed_at: float | None = None
        self._own = isinstance(out, str)
        self._f: BinaryIO = open(out, "wb") if isinstance(out, str) else out  # noqa: SIM115
        self._lock = threading.Lock()
        self._f.write(PCAP_GLOBAL.pack(PCAP_MAGIC, 2, 4, 0, 0, snaplen, LINKTYPE_ETHERNET))
        self.frames = 0

    def write(self, t: float, frame: bytes | bytearray) -> None:
        """Append one frame seen at time ``t`` (Unix or clock time, see the class docstring)."""
        sec = int(t)
        usec = round((t - sec) * 1e6)
        if self.epoch:
            whole = int(self.epoch)
            sec += whole
            usec += round((self.epoch - whole) * 1e6)
        sec, usec = sec + usec // 1_000_000, usec % 1_000_000
        with self._lock:
            self._f.write(PCAP_RECORD.pack(sec, usec, len(frame), len(frame)))
            self._f.write(frame)
            self.frames += 1
            if self._flushed_at is None or not 0 <= t - self._flushed_at < self.flush_period:
                self._flushed_at = t
                self._f.flush()

    def flush(self) -> None:
        """Push what is written to the file now (a capture read while the wire still runs)."""
        with self._lock:
            self._f.flush()

    def close(self) -> None:
        """Flush, and close the file when the writer opened it (a stream given to it stays open)."""
        with self._lock:
            self._f.flush()
            if self._own:
                self._f.close()


def read_pcap(data: bytes) -> list[tuple[float, bytes]]:
    """Parse a pcap written by :class:`PcapWriter` (for tests and tools)."""
    magic, _vmaj, _vmin, _tz, _sig, _snap, link = PCAP_GLOBAL.unpack_from(data, 0)
    if magic != PCAP_MAGIC or link != LINKTYPE_ETHERNET:
        raise PcapFormatError("not an Ethernet pcap of this writer's format")
    pos = PCAP_GLOBAL.size
    out: list[tuple[float, bytes]] = []
    while pos + PCAP_RECORD.size <= len(data):
        sec, usec, incl, _orig = PCAP_RECORD.unpack_from(data, pos)
        pos += PCAP_RECORD.size
        out.append((sec + usec / 1e6, data[pos:pos + incl]))
        pos += incl
    return out
