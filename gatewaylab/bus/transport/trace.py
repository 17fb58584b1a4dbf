"""Bus traces, streamed to disk: python-can's writers (.log candump, .asc, .blf, .csv, .trc, .txt)
and pcap / pcapng with the SocketCAN link type (Wireshark and tshark open them).

Every frame is written as it completes; the file is flushed at most ``FLUSH_PERIOD`` after a frame
(a timer on the bus clock), so ``tail -f`` shows the traffic and a killed rig loses at most that
much. Timestamps are Unix time: ``clock.wall_epoch + t`` for a frame that completed at clock time
``t``, the one time base of traces, client timestamps and the demo (docs/rig.md).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import BinaryIO, Protocol

import can

from ...common.clock import TimerHandle
from ...common.errors import ConfigError
from ..bus import VirtualBus
from ..frame import CanFrame

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
        record = socketcan_record(frame)
        usec_total = self.epoch_us + round(t * 1e6)
        self.f.write(_PCAP_RECORD.pack(usec_total // 1_000_000, usec_total % 1_000_000, len(record), len(record)))
        self.f.write(record)

    def flush(self) -> None:
        self.f.flush()

    def close(self) -> None:
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
        record = socketcan_record(frame)
        ns = self.epoch_ns + round(t * 1e9)
        self._block(0x00000006, _EPB.pack(0, ns >> 32, ns & 0xFFFFFFFF, len(record), len(record))
                    + record)

    def flush(self) -> None:
        self.f.flush()

    def close(self) -> None:
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
        self.writer.on_message_received(frame.to_message(self.epoch + t, self.channel))

    def flush(self) -> None:
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
        self.writer.stop()


class Trace:
    """Records every frame that completes on a bus, streamed to ``path`` (format from the suffix)."""

    def __init__(self, bus: VirtualBus, path: Path, epoch: float | None = None,
                 flush_period: float = FLUSH_PERIOD) -> None:
        suffix = check_trace_path(path)
        self.bus = bus
        self.path = Path(path)
        #: Unix time of bus time 0 (the clock's ``wall_epoch``): every timestamp is ``epoch + t``.
        self.epoch = bus.clock.wall_epoch if epoch is None else epoch
        self.frames = 0
        self.flush_period = flush_period
        #: The pending flush: scheduled by the first frame after a flush, so an idle bus has no timer.
        self._flush_timer: TimerHandle | None = None
        self._sink: _Sink
        if suffix == ".pcap":
            self._sink = PcapSink(self.path, self.epoch)
        elif suffix == ".pcapng":
            self._sink = PcapngSink(self.path, self.epoch, bus.name)
        else:
            self._sink = PythonCanSink(self.path, self.epoch, bus.name)
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
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        self.bus.remove_monitor(self._on_frame)
        self._sink.close()
