"""Raw-socket transport: a segment answering EtherCAT frames on a named network interface.

An AF_PACKET socket bound to EtherType 0x88A4 is busy-polled in its own thread (blocking recv
adds 50-300 us and occasional ms stalls on a VM, see shared notes 'soem-interop'); frames the
socket itself sent (PACKET_OUTGOING) are ignored. Protocol state is touched only under
``clock.lock``; with ``drive_clock`` the thread also runs due clock events (standalone use
without a rig runtime, so SM watchdogs and SYNC0 keep working).

The frame loop outlives any exception raised while a frame is processed (or a clock event runs):
the frame is dropped, one log line is written and ``frame_errors`` counts it, and the next frame is
served, as a real ESC keeps forwarding whatever one frame held.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import threading
import time
from contextlib import nullcontext

from ..common.clock import Clock, RealTimeClock
from ..common.errors import ConfigError
from .datagram import ETHERTYPE_ETHERCAT
from .segment import Segment
from .wire_pcap import PcapWriter

PACKET_OUTGOING = 4
_log = logging.getLogger(__name__)
MAX_ERRORS_KEPT = 100


class WireTransport:
    """Serve ``segment`` on ``interface`` until ``stop()``."""

    def __init__(self, segment: Segment, interface: str, clock: Clock, *, busy_poll: bool = True,
                 drive_clock: bool = False, pcap: PcapWriter | None = None, cpu: int | None = None) -> None:
        self.segment = segment
        self.interface = interface
        self.clock = clock
        self.busy_poll = busy_poll
        self.drive_clock = drive_clock
        self.pcap = pcap
        self.cpu = cpu
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self.frames_in = 0
        self.frames_out = 0
        #: Frames whose processing raised (and failed receives, clock events that raised): each dropped,
        #: logged on one line, counted.
        self.frame_errors = 0
        self.errors: list[str] = []

    def start(self) -> None:
        try:
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETHERTYPE_ETHERCAT))
        except PermissionError as exc:
            raise ConfigError(f"raw sockets need CAP_NET_RAW: {exc}") from exc
        try:
            sock.bind((self.interface, ETHERTYPE_ETHERCAT))
        except OSError as exc:
            sock.close()
            raise ConfigError(f"cannot bind to interface {self.interface!r}: {exc}") from exc
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        sock.setblocking(False)
        if isinstance(self.clock.lock, nullcontext):
            self.clock.lock = threading.RLock()  # this thread and the clock's owner share the state
        self._sock = sock
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"ethercat-wire-{self.interface}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _fault(self, what: str, exc: BaseException) -> None:
        self.frame_errors += 1
        text = " ".join(str(exc).split())  # one log line, whatever the message holds
        _log.error("ethercat-wire %s: %s raised %s: %s (dropped; %d so far)", self.interface, what,
                   type(exc).__name__, text, self.frame_errors)

    def _run(self) -> None:
        if self.cpu is not None and hasattr(os, "sched_setaffinity"):
            try:
                os.sched_setaffinity(0, {self.cpu})
            except OSError:
                pass
        sock = self._sock
        assert sock is not None
        buf = bytearray(2048)
        clock = self.clock
        segment = self.segment
        pcap = self.pcap
        drive = self.drive_clock and isinstance(clock, RealTimeClock)
        busy = self.busy_poll
        next_clock = 0.0
        while self._running:
            try:
                n, addr = sock.recvfrom_into(buf)
            except BlockingIOError:
                if drive:
                    now = time.monotonic()
                    if now >= next_clock:
                        assert isinstance(clock, RealTimeClock)
                        try:
                            clock.run_due()
                        except Exception as exc:
                            self._fault("a clock event", exc)
                        next_clock = now + 0.0002
                if not busy:
                    select.select([sock], [], [], 0.001)
                continue
            except OSError as exc:
                if not self._running:
                    return
                # e.g. ENETDOWN while the interface flaps: keep serving once it is back
                if not self.errors or self.errors[-1] != str(exc):
                    self._fault("receive", exc)
                if len(self.errors) < MAX_ERRORS_KEPT:
                    self.errors.append(str(exc))
                select.select([], [], [], 0.01)
                continue
            if addr[2] == PACKET_OUTGOING:
                continue
            frame = buf[:n]
            self.frames_in += 1
            try:
                if pcap is not None:
                    pcap.write(time.time(), frame)
                with clock.lock:
                    ok = segment.process(frame)
                if not ok:
                    continue
                try:
                    sock.send(frame)
                except OSError as exc:
                    if len(self.errors) < MAX_ERRORS_KEPT:  # a storm must not grow the list without end
                        self.errors.append(str(exc))
                    continue
                self.frames_out += 1
                if pcap is not None:
                    pcap.write(time.time(), frame)
            except Exception as exc:
                self._fault(f"frame {self.frames_in}", exc)
