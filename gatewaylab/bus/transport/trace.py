"""Bus traces, streamed to disk: python-can's writers (.log candump, .asc, .blf, .csv, .trc, .txt)
and pcap / pcapng with the SocketCAN link type (Wireshark and tshark open them).

Every frame is written as it completes; the file is flushed at most ``FLUSH_PERIOD`` after a frame
(a timer on the bus clock), so ``tail -f`` shows the traffic and a killed rig loses at most that
much. Timestamps are Unix time: ``clock.wall_epoch + t`` for a frame that completed at clock time
``t``, the one time base of traces, client timestamps and the demo (docs/rig.md).
"""

from __future__ import annotations

import fcntl
import io
import os
import re
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Protocol

import can

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.errorframe import ErrorFrame
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import TimerHandle
from gatewaylab.common.errors import ConfigError, FrameError

#: The longest a written frame stays in a buffer (seconds of bus time).
FLUSH_PERIOD = 0.1

#: Suffixes ``--trace`` and :class:`Trace` accept (python-can's streaming writers plus pcap).
TRACE_FORMATS = (".asc", ".blf", ".csv", ".log", ".trc", ".txt", ".pcap", ".pcapng")

# LINKTYPE_CAN_SOCKETCAN (227): struct can_frame / canfd_frame with the CAN id in network order.
LINKTYPE_CAN_SOCKETCAN = 227
_CAN_EFF_FLAG = 0x80000000
_CAN_RTR_FLAG = 0x40000000
_CANFD_BRS = 0x01
_CANFD_ESI = 0x02
_CANFD_FDF = 0x04
_SOCKETCAN_HEADER = struct.Struct(">IBBBB")
_PCAP_GLOBAL = struct.Struct("<IHHiIII")
_PCAP_RECORD = struct.Struct("<IIII")
_PCAP_MAGIC = 0xA1B2C3D4
_BLOCK_HEAD = struct.Struct("<II")
_SHB = struct.Struct("<IHHq")
_IDB = struct.Struct("<HHI")
_EPB = struct.Struct("<IIIII")
_OPTION = struct.Struct("<HH")


def check_trace_path(path: str | Path) -> str:
    """The suffix of a trace file, or a :class:`ConfigError` naming the supported ones."""
    suffix = Path(path).suffix.lower()
    if suffix not in TRACE_FORMATS:
        raise ConfigError(f"trace file {path}: format {suffix or '(no suffix)'!r} is not supported "
                          f"(supported: {', '.join(TRACE_FORMATS)})")
    return suffix


def lock_trace_file(path: Path) -> int:
    """Create ``path`` if needed and take an exclusive lock on it (``flock``), before anything truncates
    it: a second rig given the same trace file is refused with a clear error instead of both writing
    into it (a sparse file of NULs). Returns the descriptor that holds the lock until closed."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise ConfigError(f"trace file {path}: {exc.strerror or exc}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise ConfigError(f"trace file {path} is being written by another rig (it holds the file's lock); "
                          "give each rig its own --trace file") from None
    except OSError:
        pass          # a file system without locks: record anyway
    return fd


def socketcan_record(frame: CanFrame) -> bytes:
    """A frame as Linux ``struct can_frame`` (16 bytes) or ``struct canfd_frame`` (72 bytes)."""
    can_id = frame.can_id | (_CAN_EFF_FLAG if frame.extended else 0)
    if frame.fd:
        flags = _CANFD_FDF | (_CANFD_BRS if frame.brs else 0) | (_CANFD_ESI if frame.esi else 0)
        return _SOCKETCAN_HEADER.pack(can_id, len(frame.data), flags, 0, 0) + bytes(frame.data).ljust(64, b"\0")
    if frame.rtr:
        return _SOCKETCAN_HEADER.pack(can_id | _CAN_RTR_FLAG, frame.dlc, 0, 0, 0) + bytes(8)
    return _SOCKETCAN_HEADER.pack(can_id, len(frame.data), 0, 0, 0) + bytes(frame.data).ljust(8, b"\0")


def _epoch_ns(epoch: float) -> int:
    """``epoch`` in integer nanoseconds (a float of Unix time only resolves ~0.2 us)."""
    seconds = int(epoch)
    return seconds * 1_000_000_000 + round((epoch - seconds) * 1e9)


class _Sink(Protocol):
    def write(self, frame: CanFrame, t: float) -> None:
        """``frame`` completed at clock time ``t`` (Unix time ``epoch + t``)."""
    def flush(self) -> None: ...
    def close(self) -> None: ...


def _pad4(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


class PcapSink:
    """Classic pcap (microsecond timestamps) of SocketCAN frames."""

    def __init__(self, path: Path, epoch: float) -> None:
        self.epoch_us = _epoch_ns(epoch) // 1000
        self.f: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed by close()
        self.f.write(_PCAP_GLOBAL.pack(_PCAP_MAGIC, 2, 4, 0, 0, 72, LINKTYPE_CAN_SOCKETCAN))

    def write(self, frame: CanFrame, t: float) -> None:
        """Append one frame as a SocketCAN record at its clock time."""
        record = socketcan_record(frame)
        usec_total = self.epoch_us + round(t * 1e6)
        self.f.write(_PCAP_RECORD.pack(usec_total // 1_000_000, usec_total % 1_000_000, len(record), len(record)))
        self.f.write(record)

    def flush(self) -> None:
        """Push buffered records to the file (readable by a live Wireshark)."""
        self.f.flush()

    def close(self) -> None:
        """Close the file."""
        self.f.close()


class PcapngSink:
    """pcapng: one section, one SocketCAN interface named after the bus, nanosecond timestamps."""

    def __init__(self, path: Path, epoch: float, bus_name: str) -> None:
        self.epoch_ns = _epoch_ns(epoch)
        self.f: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed by close()
        self._block(0x0A0D0D0A, _SHB.pack(0x1A2B3C4D, 1, 0, -1))   # byte-order magic, v1.0, length unknown
        name = bus_name.encode()
        options = (_OPTION.pack(2, len(name)) + _pad4(name)          # if_name
                   + _OPTION.pack(9, 1) + _pad4(b"\x09")             # if_tsresol: 10^-9 s
                   + _OPTION.pack(0, 0))
        self._block(0x00000001, _IDB.pack(LINKTYPE_CAN_SOCKETCAN, 0, 72) + options)

    def _block(self, block_type: int, body: bytes) -> None:
        body = _pad4(body)
        length = 12 + len(body)
        self.f.write(_BLOCK_HEAD.pack(block_type, length) + body + struct.pack("<I", length))

    def write(self, frame: CanFrame, t: float) -> None:
        """Append one frame as an enhanced packet block at its clock time."""
        record = socketcan_record(frame)
        ns = self.epoch_ns + round(t * 1e9)
        self._block(0x00000006, _EPB.pack(0, ns >> 32, ns & 0xFFFFFFFF, len(record), len(record))
                    + record)

    def flush(self) -> None:
        """Push buffered blocks to the file (readable by a live Wireshark)."""
        self.f.flush()

    def close(self) -> None:
        """Close the file."""
        self.f.close()


class PythonCanSink:
    """One of python-can's writers, started at ``epoch`` and flushed on demand."""

    def __init__(self, path: Path, epoch: float, channel: str) -> None:
        self.epoch = epoch
        self.channel = channel
        self.writer: can.io.generic.MessageWriter = can.Logger(str(path))
        w = self.writer
        # Relative-time formats count from the rig's clock time 0, like every other trace.
        if isinstance(w, can.ASCWriter):
            w.log_event("Start of measurement (gatewaylab: t = 0 is the rig clock's time 0)", epoch)
        elif isinstance(w, can.TRCWriter):
            w.first_timestamp = epoch
            w.write_header(epoch)
        elif isinstance(w, can.BLFWriter):
            w.start_timestamp = int(epoch * 1000) / 1000

    def write(self, frame: CanFrame, t: float) -> None:
        """Hand one frame to the python-can writer at its wall-clock time."""
        self.writer.on_message_received(frame.to_message(self.epoch + t, self.channel))

    def flush(self) -> None:
        """Make the file readable as it is (BLF: a complete container and header)."""
        w = self.writer
        if isinstance(w, can.BLFWriter):
            # a complete container and an up-to-date header: readable even if the rig is killed
            w._flush()
            f = w.file
            end = f.tell()
            f.seek(0)
            w._write_header(end)
            f.seek(end)
        file = getattr(w, "file", None)
        if file is not None and not file.closed:
            file.flush()

    def close(self) -> None:
        """Stop the python-can writer (it writes its trailer)."""
        self.writer.stop()


class Trace:
    """Records every frame that completes on a bus, streamed to ``path`` (format from the suffix)."""

    def __init__(self, bus: VirtualBus, path: Path, epoch: float | None = None,
                 flush_period: float = FLUSH_PERIOD) -> None:
        suffix = check_trace_path(path)
        self.bus = bus
        self.path = Path(path)
        self._lock_fd = lock_trace_file(self.path)
        #: Unix time of bus time 0 (the clock's ``wall_epoch``): every timestamp is ``epoch + t``.
        self.epoch = bus.clock.wall_epoch if epoch is None else epoch
        self.frames = 0
        self.flush_period = flush_period
        #: The pending flush: scheduled by the first frame after a flush, so an idle bus has no timer.
        self._flush_timer: TimerHandle | None = None
        self._sink: _Sink
        try:
            if suffix == ".pcap":
                self._sink = PcapSink(self.path, self.epoch)
            elif suffix == ".pcapng":
                self._sink = PcapngSink(self.path, self.epoch, bus.name)
            else:
                self._sink = PythonCanSink(self.path, self.epoch, bus.name)
        except BaseException:
            os.close(self._lock_fd)
            raise
        bus.add_monitor(self._on_frame)

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        self.frames += 1
        self._sink.write(frame, t)
        if self._flush_timer is None:
            self._flush_timer = self.bus.clock.call_later(self.flush_period, self.flush)

    def flush(self) -> None:
        """Push written frames to the file (a timer does it ``flush_period`` after a frame)."""
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        self._sink.flush()

    def close(self) -> None:
        """Stop recording: remove the monitor, flush and close the file."""
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        self.bus.remove_monitor(self._on_frame)
        try:
            self._sink.close()
        finally:
            if self._lock_fd >= 0:
                os.close(self._lock_fd)
                self._lock_fd = -1


# -- reading traces back (gatewaylab monitor --replay, gatewaylab plot) ------------------------------
class TraceError(ConfigError):
    """A trace file that cannot be read: names the file and the line (text) or byte offset (binary)."""


TraceItem = tuple[CanFrame | ErrorFrame, float]
_PCAPNG_SHB = 0x0A0D0D0A
_PCAP_MAGICS = {0xA1B2C3D4: ("<", 1e-6), 0xD4C3B2A1: (">", 1e-6), 0xA1B23C4D: ("<", 1e-9), 0x4D3CB2A1: (">", 1e-9)}
_LINKTYPE_LINUX_SLL = 113
_SOCKETCAN_ERR_FLAG = 0x20000000


def _socketcan_item(record: bytes, t: float, where: str) -> TraceItem:
    """One SocketCAN ``can_frame`` / ``canfd_frame`` record (can_id in network order, as Wireshark
    writes LINKTYPE_CAN_SOCKETCAN) as a frame or an error frame."""
    if len(record) < _SOCKETCAN_HEADER.size:
        raise TraceError(f"{where}: a SocketCAN record of {len(record)} bytes (at least 8)")
    can_id, length, flags, _, _ = _SOCKETCAN_HEADER.unpack_from(record)
    data = bytes(record[8:8 + length])
    if len(data) < length:
        raise TraceError(f"{where}: the record says {length} data bytes but carries {len(data)}")
    if can_id & _SOCKETCAN_ERR_FLAG:
        return ErrorFrame(can_id & 0x1FFFFFFF, data.ljust(8, b"\0")[:8]), t
    extended = bool(can_id & _CAN_EFF_FLAG)
    ident = can_id & (0x1FFFFFFF if extended else 0x7FF)
    fd = bool(flags & _CANFD_FDF) or len(record) >= 72
    try:
        if can_id & _CAN_RTR_FLAG and not fd:
            return CanFrame(ident, b"", extended, rtr=True, dlc=min(length, 8)), t
        return CanFrame(ident, data, extended, fd=fd, brs=bool(flags & _CANFD_BRS) and fd,
                        esi=bool(flags & _CANFD_ESI) and fd), t
    except FrameError as exc:
        raise TraceError(f"{where}: {exc}") from None


def parse_pcap(data: bytes, name: str = "trace", channels: list[str] | None = None) -> list[TraceItem]:
    """The CAN frames of a classic pcap file (LINKTYPE_CAN_SOCKETCAN); pure, errors name the offset.
    ``channels`` gets one channel name per item ("": a pcap names none)."""
    if len(data) < _PCAP_GLOBAL.size:
        raise TraceError(f"{name}: offset 0: {len(data)} bytes, too short for a pcap header (24)")
    magic = struct.unpack_from("<I", data)[0]
    if magic not in _PCAP_MAGICS:
        raise TraceError(f"{name}: offset 0: not a pcap file (magic 0x{magic:08X})")
    order, unit = _PCAP_MAGICS[magic]
    linktype = struct.unpack_from(order + "I", data, 20)[0] & 0x0FFFFFFF
    if linktype != LINKTYPE_CAN_SOCKETCAN:
        raise TraceError(f"{name}: offset 20: link type {linktype}, not SocketCAN CAN ({LINKTYPE_CAN_SOCKETCAN})")
    record = struct.Struct(order + "IIII")
    out: list[TraceItem] = []
    pos = _PCAP_GLOBAL.size
    while pos < len(data):
        if len(data) - pos < record.size:
            raise TraceError(f"{name}: offset {pos}: truncated record header ({len(data) - pos} bytes)")
        sec, frac, incl, _orig = record.unpack_from(data, pos)
        if incl > 72 or pos + record.size + incl > len(data):
            raise TraceError(f"{name}: offset {pos}: record of {incl} bytes does not fit "
                             f"({'longer than a CAN FD frame' if incl > 72 else 'file ends'})")
        body = data[pos + record.size:pos + record.size + incl]
        out.append(_socketcan_item(body, sec + frac * unit, f"{name}: offset {pos}"))
        if channels is not None:
            channels.append("")
        pos += record.size + incl
    return out


def parse_pcapng(data: bytes, name: str = "trace", channels: list[str] | None = None) -> list[TraceItem]:
    """The CAN frames of a pcapng file (SocketCAN interfaces; enhanced and simple packet blocks).
    ``channels`` gets the interface name (if_name) of each item ("" for an unnamed interface)."""
    out: list[TraceItem] = []
    pos = 0
    order = "<"
    interfaces: list[tuple[int, float, str]] = []   # (link type, seconds per timestamp unit, if_name)
    while pos < len(data):
        if len(data) - pos < 12:
            raise TraceError(f"{name}: offset {pos}: truncated block ({len(data) - pos} bytes)")
        btype = struct.unpack_from(order + "I", data, pos)[0]
        if btype == _PCAPNG_SHB:
            bom = struct.unpack_from("<I", data, pos + 8)[0]
            if bom == 0x1A2B3C4D:
                order = "<"
            elif bom == 0x4D3C2B1A:
                order = ">"
            else:
                raise TraceError(f"{name}: offset {pos + 8}: bad byte-order magic 0x{bom:08X}")
            interfaces = []
        elif pos == 0:
            raise TraceError(f"{name}: offset 0: not a pcapng file (first block 0x{btype:08X}, "
                             "expected a section header 0x0A0D0D0A)")
        length = struct.unpack_from(order + "I", data, pos + 4)[0]
        if length < 12 or length % 4 or pos + length > len(data):
            raise TraceError(f"{name}: offset {pos}: block length {length} does not fit the file")
        body = data[pos + 8:pos + length - 4]
        if btype == 0x00000001:                          # interface description
            linktype = struct.unpack_from(order + "H", body)[0]
            unit = 1e-6
            if_name = ""
            opt = 8
            while opt + 4 <= len(body):
                code, olen = struct.unpack_from(order + "HH", body, opt)
                if code == 0:
                    break
                if code == 9 and olen >= 1:
                    r = body[opt + 4]
                    unit = 2.0 ** -(r & 0x7F) if r & 0x80 else 10.0 ** -r
                elif code == 2:
                    if_name = body[opt + 4:opt + 4 + olen].rstrip(b"\0").decode("utf-8", "replace")
                opt += 4 + olen + (-olen % 4)
            interfaces.append((linktype, unit, if_name))
        elif btype in (0x00000006, 0x00000003):          # enhanced / simple packet
            if btype == 0x00000006:
                if len(body) < 20:
                    raise TraceError(f"{name}: offset {pos}: packet block too short")
                iface, hi, lo, incl, _orig = struct.unpack_from(order + "IIIII", body)
                packet, stamp_at = body[20:20 + incl], (hi << 32) | lo
            else:
                iface, stamp_at = 0, 0
                incl = struct.unpack_from(order + "I", body)[0]
                packet = body[4:4 + incl]
            if iface >= len(interfaces):
                raise TraceError(f"{name}: offset {pos}: packet of interface {iface}, which was not described")
            linktype, unit, if_name = interfaces[iface]
            if linktype == LINKTYPE_CAN_SOCKETCAN:
                out.append(_socketcan_item(packet, stamp_at * unit, f"{name}: offset {pos}"))
                if channels is not None:
                    channels.append(if_name)
        pos += length
    return out


class _CountedLines(io.StringIO):
    """A text file for python-can's readers that knows which line they are on (for error messages)."""

    lineno = 0
    #: the line the reader read last (the one its message comes from)
    last = ""

    def readline(self, size: int | None = -1, /) -> str:  # type: ignore[override]
        line = super().readline(-1 if size is None else size)
        if line:
            self.lineno += 1
            self.last = line
        return line


_PRINTER_LINE = re.compile(
    r"Timestamp:\s*(?P<t>[-\d.]+)\s+ID:\s*(?P<id>[0-9a-fA-F]+)\s+(?P<x>[SX])\s+(?:Rx|Tx)\s+(?P<flags>.*?)"
    r"DL:\s*(?P<dl>\d+)\s*(?P<data>(?:[0-9a-fA-F]{2}\s)*(?:[0-9a-fA-F]{2})?)\s*(?:Channel:\s*(?P<ch>\S*).*)?$")


def _printer_lines(text: str, name: str, channels: list[str] | None = None) -> list[TraceItem]:
    """python-can's Printer (``.txt``): ``str(Message)`` per line."""
    out: list[TraceItem] = []
    for n, raw in enumerate(text.splitlines(), 1):
        if not raw.strip():
            continue
        m = _PRINTER_LINE.match(raw.strip())
        if m is None:
            raise TraceError(f"{name}: line {n}: not a python-can Printer line: {raw.strip()[:60]!r}")
        flags = m["flags"].split()
        try:
            if "E" in flags:
                out.append((ErrorFrame(int(m["id"], 16), bytes.fromhex(m["data"]).ljust(8, b"\0")[:8]), float(m["t"])))
            elif "R" in flags:
                out.append((CanFrame(int(m["id"], 16), b"", m["x"] == "X", rtr=True, dlc=int(m["dl"])), float(m["t"])))
            else:
                fd = "F" in flags
                out.append((CanFrame(int(m["id"], 16), bytes.fromhex(m["data"]), m["x"] == "X", fd=fd,
                                     brs=fd and "BS" in flags, esi=fd and "EI" in flags), float(m["t"])))
        except (FrameError, ValueError) as exc:
            raise TraceError(f"{name}: line {n}: {exc}") from None
        if channels is not None:
            channels.append(m["ch"] or "")
    return out


_TEXT_READERS = {".asc": "ASCReader", ".log": "CanutilsLogReader", ".csv": "CSVReader", ".trc": "TRCReader"}


def read_trace(path: str | Path, channels: list[str] | None = None) -> list[TraceItem]:
    """Every frame and error frame of a trace the rig writes (``--trace``: .asc .blf .csv .log .trc
    .txt .pcap .pcapng), with its Unix timestamp. Anything unreadable raises one :class:`TraceError`
    naming the file and the line (text formats) or the byte offset (binary ones).

    ``channels`` (a list) gets the channel of every item, as the trace names it: candump .log and
    python-can's .txt the interface name (``can0``), pcapng the interface's name, Vector .asc / .blf
    and .trc their channel number (``1``, ``2``, ... as written in the file); "" when the format names
    none (.pcap, .csv)."""
    path = Path(path)
    name = str(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise TraceError(f"{name}: {exc.strerror or exc}") from None
    suffix = path.suffix.lower()
    magic = struct.unpack_from("<I", data)[0] if len(data) >= 4 else None
    if suffix == ".pcapng" or magic == _PCAPNG_SHB:
        return parse_pcapng(data, name, channels)
    if suffix == ".pcap" or magic in _PCAP_MAGICS:
        return parse_pcap(data, name, channels)
    if suffix == ".blf":
        return _python_can_binary(path, name, channels)
    if suffix not in (*_TEXT_READERS, ".txt"):
        raise TraceError(f"{name}: format {suffix or '(no suffix)'!r} is not one the rig writes "
                         f"({', '.join(TRACE_FORMATS)})")
    nul = data.find(b"\0")
    if nul >= 0:
        line = data.count(b"\n", 0, nul) + 1
        raise TraceError(f"{name}: line {line} (offset {nul}): a NUL byte; not a {suffix} text trace "
                         "(a file cut short or overwritten?)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise TraceError(f"{name}: line {line} (offset {exc.start}): not UTF-8 text") from None
    if suffix == ".txt":
        return _printer_lines(text, name, channels)
    lines = _CountedLines(text)
    reader = getattr(can, _TEXT_READERS[suffix])(lines)
    out: list[TraceItem] = []
    try:
        for msg in reader:
            if suffix == ".asc" and msg.is_fd and msg.is_remote_frame:
                msg = asc_empty_fd_frame(msg, lines.last)
            out.append(_message_item(msg, f"{name}: line {lines.lineno}"))
            if channels is not None:
                channels.append(_channel_name(msg))
    except TraceError:
        raise
    except Exception as exc:    # python-can's readers raise anything on bad input
        raise TraceError(f"{name}: line {lines.lineno}: not a {suffix} line ({_first_line(exc)})") from None
    if not out and any(ln.strip() and not ln.lstrip().startswith(("#", ";", "//")) for ln in text.splitlines()):
        first = next(n for n, ln in enumerate(text.splitlines(), 1) if ln.strip())
        if suffix not in (".asc", ".trc") or not _has_header_only(text, suffix):
            raise TraceError(f"{name}: line {first}: no CAN frame in this {suffix} file "
                             f"({text.splitlines()[first - 1].strip()[:60]!r})")
    return out


#: Vector ASC ``CANFD`` event flags (the same bits as BLF's CAN_FD_MESSAGE_64): remote frame, EDL (a
#: CAN FD frame; without it the line is a classic frame on an FD channel)
_ASC_FD_FLAG_REMOTE = 0x0010
_ASC_FD_FLAG_EDL = 0x1000


def asc_empty_fd_frame(msg: can.Message, line: str) -> can.Message:
    """The frame of an ``.asc`` ``CANFD`` line that python-can's ASCReader took for a remote frame.

    The reader (python-can 4.x ``ASCReader._process_fd_can_frame``) decides "remote" from a data length of
    0 alone, so every CAN FD frame without data (``123##0`` in candump's notation) comes back as an FD
    remote frame, which CAN FD does not have (ISO 11898-1:2015: an FD frame's RRS bit is always
    dominant). The line's flags field says what it is: EDL set -> a CAN FD data frame of length 0; EDL
    clear -> a classic frame on an FD channel, remote if the remote flag is set. A line without a
    readable flags field (a shorter form from another tool) is an FD frame of length 0. docs/monitor.md
    "CAN FD frames without data in .asc traces" reports the reader's behaviour."""
    flags = _asc_fd_flags(line)
    classic = flags is not None and not flags & _ASC_FD_FLAG_EDL
    if classic and flags is not None and flags & _ASC_FD_FLAG_REMOTE:
        return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                           is_extended_id=msg.is_extended_id, is_remote_frame=True, dlc=min(msg.dlc, 8),
                           channel=msg.channel, is_rx=msg.is_rx)
    fd = not classic
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                       is_extended_id=msg.is_extended_id, data=b"", is_fd=fd,
                       bitrate_switch=fd and msg.bitrate_switch, error_state_indicator=fd and msg.error_state_indicator,
                       channel=msg.channel, is_rx=msg.is_rx)


def _asc_fd_flags(line: str) -> int | None:
    """The flags field (hex) of a ``CANFD`` line with data length 0: ``<time> CANFD <ch> <dir> <id>
    [<symbolic name>] <brs> <esi> <dlc> 0 <duration> <length> <flags> ...`` (Vector ASC)."""
    words = line.split()
    try:
        at = words.index("CANFD") + 4           # the first word after the id
        if not words[at].isdigit():
            at += 1                             # a symbolic name (python-can's reader decides the same way)
        if int(words[at + 3]) != 0:
            return None
        return int(words[at + 6], 16)
    except (ValueError, IndexError):
        return None


def _has_header_only(text: str, suffix: str) -> bool:
    """An .asc / .trc file that holds only its header (a rig that recorded no frame)."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if suffix == ".trc":
        return all(ln.startswith(";") for ln in lines)
    return all(ln.split()[0] in ("date", "base", "internal", "Begin", "End", "no", "//")
               or "Start of measurement" in ln for ln in lines)


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return (text[:120] + "...") if len(text) > 120 else text or type(exc).__name__


def _message_item(msg: can.Message, where: str) -> TraceItem:
    if msg.is_error_frame:
        return ErrorFrame(msg.arbitration_id & 0x1FFFFFFF, bytes(msg.data or b"").ljust(8, b"\0")[:8]), msg.timestamp
    try:
        if not msg.is_fd and len(msg.data or b"") > 8:
            msg.is_fd = True          # a format without an FD flag (.csv) holding a CAN FD frame
        return CanFrame.from_message(msg), msg.timestamp
    except FrameError as exc:
        raise TraceError(f"{where}: {exc}") from None


def _channel_name(msg: can.Message) -> str:
    """python-can's channel of a message read from a trace: a name as it is, a number (python-can's
    readers count Vector's channels from 0) as the file writes it, from 1."""
    channel = msg.channel
    if channel is None:
        return ""
    return str(channel + 1) if isinstance(channel, int) else str(channel)


def _python_can_binary(path: Path, name: str, channels: list[str] | None = None) -> list[TraceItem]:
    out: list[TraceItem] = []
    try:
        reader = can.BLFReader(str(path))
        for msg in reader:
            out.append(_message_item(msg, f"{name}: frame {len(out) + 1}"))
            if channels is not None:
                channels.append(_channel_name(msg))
    except TraceError:
        raise
    except Exception as exc:    # python-can's reader raises anything on bad input
        raise TraceError(f"{name}: after frame {len(out)}: not a readable BLF file ({_first_line(exc)})") from None
    return out


# -- a time window of a trace (gatewaylab plot / dump / monitor --replay --from --to) -------------------
#: A timestamp at or above this is Unix time; below it, time since the rig started (a rig's .asc trace).
UNIX_TIME_FROM = 1e8


def trace_origin(first_stamp: float) -> float:
    """Time 0 of trace time, from the trace's first timestamp: a trace in Unix time (.log, .blf, .pcap,
    ...) counts from its first frame (the rig's start is not in the file); one already relative to the
    rig's start (.asc) counts from there. The times ``monitor --replay`` prints and ``plot`` draws."""
    return first_stamp if first_stamp >= UNIX_TIME_FROM else 0.0


@dataclass(frozen=True, slots=True)
class TimeBound:
    """One end of a :class:`TimeWindow`: ``seconds`` of trace time (a Unix time when at least
    :data:`UNIX_TIME_FROM`), or with ``relative`` (written ``+S``) seconds after a reference: for
    ``--from`` the trace's first frame, for ``--to`` the window's start."""

    seconds: float
    relative: bool = False

    @classmethod
    def parse(cls, text: str, option: str) -> TimeBound:
        """``T`` or ``+S`` (seconds, >= 0); anything else is a :class:`ConfigError` naming ``option``."""
        body = text.strip()
        relative = body.startswith("+")
        try:
            seconds = float(body[1:] if relative else body)
        except ValueError:
            seconds = float("nan")
        if not seconds >= 0 or seconds == float("inf"):
            raise ConfigError(f"{option} wants seconds of trace time (T) or seconds after a reference (+S), "
                              f"0 or more, got {text!r}")
        return cls(seconds, relative)


@dataclass(frozen=True, slots=True)
class TimeWindow:
    """The frames of a trace from ``start`` (included) to ``end`` (excluded), in trace time.

    ``--from T``: T s of trace time (see :func:`trace_origin`; a Unix time if T >= 1e8); ``--from +S``:
    S s after the trace's first frame. ``--to T``: up to trace time T; ``--to +D``: D s after the
    window's start (``--from``, else the first frame). No bound: the trace's start / end."""

    start: TimeBound | None = None
    end: TimeBound | None = None

    @classmethod
    def parse(cls, start: str | None, end: str | None) -> TimeWindow:
        """``--from`` / ``--to`` as given (None: not given); an empty window is refused here when the
        two forms can be compared without the trace (otherwise by :meth:`bounds`)."""
        window = cls(None if start is None else TimeBound.parse(start, "--from"),
                     None if end is None else TimeBound.parse(end, "--to"))
        low, high = window.start, window.end
        if high is not None and (
                (high.relative and high.seconds == 0)
                or (low is not None and not low.relative and not high.relative
                    and (low.seconds >= UNIX_TIME_FROM) == (high.seconds >= UNIX_TIME_FROM)
                    and high.seconds <= low.seconds)):
            raise ConfigError(f"--to {end} is not after --from {start or '(the first frame)'}: the window is empty")
        return window

    def __bool__(self) -> bool:
        return self.start is not None or self.end is not None

    def bounds(self, first_stamp: float) -> tuple[float, float]:
        """``(low, high)`` in the trace's own timestamps, for a trace whose first timestamp is
        ``first_stamp``; a :class:`ConfigError` when ``--to`` is not after ``--from``."""
        origin = trace_origin(first_stamp)

        def at(bound: TimeBound, reference: float) -> float:
            if bound.relative:
                return reference + bound.seconds
            return bound.seconds if bound.seconds >= UNIX_TIME_FROM else origin + bound.seconds
        low = -float("inf") if self.start is None else at(self.start, first_stamp)
        high = float("inf") if self.end is None else at(
            self.end, first_stamp if self.start is None else low)
        if high <= low:
            raise ConfigError(f"--to ({high - origin:.6f} s of trace time) is not after --from "
                              f"({low - origin:.6f} s)")
        return low, high

    def select(self, items: Iterable[TraceItem | None]) -> Iterator[TraceItem]:
        """The items of ``items`` (a whole trace, first item first; None, a live view's idle tick, is
        skipped) inside the window."""
        bounds: tuple[float, float] | None = None
        for item in items:
            if item is None:
                continue
            if bounds is None:
                bounds = self.bounds(item[1])
            if bounds[0] <= item[1] < bounds[1]:
                yield item
