"""pcap capture of EtherCAT frames (link type 1, Ethernet), readable by Wireshark's EtherCAT dissector."""

from __future__ import annotations

import struct
import threading
from typing import BinaryIO

PCAP_GLOBAL = struct.Struct("<IHHiIII")
PCAP_RECORD = struct.Struct("<IIII")
LINKTYPE_ETHERNET = 1
PCAP_MAGIC = 0xA1B2C3D4


class PcapWriter:
    """Appends frames with their timestamps; safe to call from the wire thread and others."""

    def __init__(self, out: BinaryIO | str, snaplen: int = 65535) -> None:
        self._own = isinstance(out, str)
        self._f: BinaryIO = open(out, "wb") if isinstance(out, str) else out  # noqa: SIM115
        self._lock = threading.Lock()
        self._f.write(PCAP_GLOBAL.pack(PCAP_MAGIC, 2, 4, 0, 0, snaplen, LINKTYPE_ETHERNET))
        self.frames = 0

    def write(self, t: float, frame: bytes | bytearray) -> None:
        sec = int(t)
        usec = round((t - sec) * 1e6)
        if usec >= 1_000_000:
            sec, usec = sec + 1, usec - 1_000_000
        with self._lock:
            self._f.write(PCAP_RECORD.pack(sec, usec, len(frame), len(frame)))
            self._f.write(frame)
            self.frames += 1

    def flush(self) -> None:
        with self._lock:
            self._f.flush()

    def close(self) -> None:
        with self._lock:
            self._f.flush()
            if self._own:
                self._f.close()


def read_pcap(data: bytes) -> list[tuple[float, bytes]]:
    """Parse a pcap written by :class:`PcapWriter` (for tests and tools)."""
    magic, _vmaj, _vmin, _tz, _sig, _snap, link = PCAP_GLOBAL.unpack_from(data, 0)
    if magic != PCAP_MAGIC or link != LINKTYPE_ETHERNET:
        raise ValueError("not an Ethernet pcap of this writer's format")
    pos = PCAP_GLOBAL.size
    out: list[tuple[float, bytes]] = []
    while pos + PCAP_RECORD.size <= len(data):
        sec, usec, incl, _orig = PCAP_RECORD.unpack_from(data, pos)
        pos += PCAP_RECORD.size
        out.append((sec + usec / 1e6, data[pos:pos + incl]))
        pos += incl
    return out
