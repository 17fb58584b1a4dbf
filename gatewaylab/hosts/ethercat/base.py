"""Datagram exchange of the in-process master (SOEM's ethercatbase): one frame out, its datagrams back.

Every other part of :class:`~gatewaylab.hosts.ethercat.master.Master` (configuration, mailbox,
CoE, FoE, DC, process data) talks to the slaves through one :class:`Port`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.errors import MasterError, WorkingCounterError
from gatewaylab.ethercat.segment import Segment

__all__ = ["U8", "U16", "U32", "U64", "Port"]


U8 = struct.Struct("<B")
U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
U64 = struct.Struct("<Q")


class Port:
    """The frame path to the slaves (a segment in-process or a link function), so every command goes one way."""

    def __init__(self, clock: Clock, segment: Segment | None, link: Callable[[bytes], bytes | None] | None,
                 timeout: float, capture: Callable[[float, bytes], None] | None) -> None:
        if segment is None and link is None:
            raise MasterError("a master needs a segment or a link")
        self.clock = clock
        self.segment = segment
        self.link = link
        #: Seconds a mailbox poll (``wait_until``) may take before TimeoutError_.
        self.timeout = timeout
        #: Called with (clock time, frame) for every frame out and back, e.g. ``PcapWriter.write``.
        self.capture = capture
        self.frames = 0
        self.lost_frames = 0
        self.index = 0

    def exchange(self, datagrams: list[Datagram]) -> tuple[Datagram, ...]:
        """Send one frame and return its datagrams as they came back: the one path every command takes."""
        raw = encode_frame(Frame(tuple(datagrams)))
        self.frames += 1
        if self.capture is not None:
            self.capture(self.clock.now(), raw)
        if self.segment is not None:
            buf = bytearray(raw)
            faults = self.segment.line_faults
            if faults is not None and faults.engaged:   # line faults armed (ethercat/line_faults.py)
                ok = faults.serve_now(self.segment, buf, self.clock.now())
            else:
                ok = self.segment.process(buf)
            back: bytes | None = bytes(buf) if ok else None
        elif self.link is not None:
            back = self.link(raw)
        else:  # __init__ refuses a port without either
            raise MasterError("a master needs a segment or a link")
        if back is None:
            self.lost_frames += 1
            raise TimeoutError_("frame lost")
        if self.capture is not None:
            self.capture(self.clock.now(), back)
        return decode_frame(back).datagrams

    def next_index(self) -> int:
        """The datagram index for the next command, so replies can be told apart in a capture."""
        self.index = (self.index + 1) & 0xFF
        return self.index

    def one(self, command: Command, address: int, data: bytes) -> Datagram:
        """One datagram in its own frame, as it came back (the caller checks the working counter)."""
        return self.exchange([Datagram(command, self.next_index(), address, data)])[0]

    def phys(self, command: Command, adp: int, ado: int, data: bytes) -> Datagram:
        """A position/station addressed command (APxx, FPxx, Bxx): ADP in the low word, ADO in the high."""
        return self.one(command, (adp & 0xFFFF) | (ado << 16), data)

    def fprd(self, station: int, ado: int, length: int) -> bytes:
        """Read a register of one configured slave (FPRD), raising unless exactly that slave answered."""
        d = self.phys(Command.FPRD, station, ado, bytes(length))
        if d.wkc != 1:
            raise WorkingCounterError(f"FPRD 0x{station:04X}:0x{ado:04X} wkc {d.wkc}", d.wkc)
        return d.data

    def fpwr(self, station: int, ado: int, data: bytes) -> None:
        """Write a register of one configured slave (FPWR), raising unless exactly that slave answered."""
        d = self.phys(Command.FPWR, station, ado, data)
        if d.wkc != 1:
            raise WorkingCounterError(f"FPWR 0x{station:04X}:0x{ado:04X} wkc {d.wkc}", d.wkc)

    def wait_until(self, check: Callable[[], bool], poll: float, what: str = "mailbox timeout") -> None:
        """Call ``check`` (it sends a frame) until it holds, waiting ``poll`` seconds on the clock between calls."""
        deadline = self.clock.now() + self.timeout
        while not check():
            if self.clock.now() >= deadline:
                raise TimeoutError_(what)
            self.clock.wait(poll)
