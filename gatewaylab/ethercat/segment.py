"""Several slaves in one line: a frame passes slave 0 first, then 1, ... and returns to the master.

``process`` works in place on a received Ethernet frame and says whether to send it back.
Malformed frames are counted and dropped (a real ESC forwards them with a broken FCS, which the
master's NIC discards), and slave 0's invalid-frame counter (0x0300) goes up.

Contract: ``process`` never raises for anything a frame holds. Each datagram runs on each ESC on
its own: should one raise (a defect of the emulator or of a device's application, never expected),
that datagram is left as it is for that slave (no working counter increment), the error is counted
(``stats.datagram_errors``, the ESC's ``stats.datagram_errors``) and logged on one line (the first
few, then every 1000th), and the frame's other datagrams and slaves are served as usual; a real
ESC processes every datagram whatever its firmware does.

Ports and cables (ethercat/ring.py): which slaves a frame reaches follows the links of their ports -- a line,
or a ring whose last slave is cabled to the master's secondary interface (:meth:`Segment.process_secondary`
serves frames from there), open ports (:meth:`Segment.cut`), hot-connect groups (:meth:`Segment.detach`).

The frame path is the ESCs' work only where the applications allow it: outputs of an application with
``SlaveApplication.outputs_in_frame`` False (the drives, the ECAN-Lite) reach it after the frame, and so does
the master's read of the inputs for one with ``inputs_read_in_frame`` False (the ECAN-Lite), in
:meth:`Segment.after_frame`, which a transport calls once it has sent the frame back (the wire thread)
and :meth:`Segment.process` runs itself at its end unless asked to ``defer`` it (the wire then runs it
once its socket holds no other frame). A raising application
there is isolated per slave as a datagram is.
"""

from __future__ import annotations

import logging
import struct
from collections import deque
from dataclasses import dataclass, field
from typing import Final, Protocol

from gatewaylab.ethercat.datagram import ETH_HEADER_LEN, ETHERTYPE_ETHERCAT, LEN_MASK, MORE
from gatewaylab.ethercat.errors import SlavePositionError
from gatewaylab.ethercat.esc import REG_RX_ERROR, Esc
from gatewaylab.ethercat.esc_dc import place_line
from gatewaylab.ethercat.esc_dc_clock import FrameTime
from gatewaylab.ethercat.line_faults import LineFaults
from gatewaylab.ethercat.ring import LOST, PORT_A, routes
from gatewaylab.ethercat.slave import Slave

__all__ = ["LOG_EVERY", "LOG_FIRST", "FrameObserver", "Segment", "SegmentStats"]


_U16: Final = struct.Struct("<H")
_BE16: Final = struct.Struct("!H")
_DG_HDR: Final = struct.Struct("<B5xH")  # cmd, (idx + address skipped), len/flags
#: The circulating bit of a datagram's length field (ETG.1000.4 datagram header, bit 14), high byte.
_CIRCULATING: Final = 0x40
_log = logging.getLogger(__name__)
#: Datagram errors logged one line each before only every ``LOG_EVERY``-th is.
LOG_FIRST: Final = 10
LOG_EVERY: Final = 1000


@dataclass(slots=True)
class SegmentStats:
    """Counters of one line: frames served and dropped, datagram executions that raised."""

    frames: int = 0
    bad_frames: int = 0
    datagrams: int = 0
    #: (datagram, slave) executions that raised; each isolated (see the module docstring)
    datagram_errors: int = 0
    #: the last few of them: "slave N cmd C: ExceptionType: text"
    errors: deque[str] = field(default_factory=lambda: deque(maxlen=20))


class FrameObserver(Protocol):
    """Told of every frame the segment served, once its datagrams ran (a scenario's milestones: a state
    reached, process-data cycles, an SDO request; gatewaylab.ethercat.milestones). None -- the default --
    costs the frame path one check."""

    def frame_served(self, frame: bytearray, datagrams: list[tuple[int, int, int]]) -> None:
        """``datagrams``: (offset of the datagram header in ``frame``, command, data length) of each."""


class Segment:
    """The slaves of one EtherCAT line, in position order."""

    def __init__(self, slaves: list[Slave]) -> None:
        self.slaves = list(slaves)
        self.stats = SegmentStats()
        #: positions of the slaves unplugged from the line (fault injection)
        self.unplugged: set[int] = set()
        #: faults of the line to the master (ethercat/line_faults.py), put here when the rig arms the first
        #: one; transports serve frames through it while it is ``engaged``
        self.line_faults: LineFaults | None = None
        #: the master's secondary interface is cabled to the last slave's port 1 (cable redundancy, ring.py)
        self.redundant = False
        #: open gaps (cables without a link, ring.py numbering): gap -> how many faults hold it open
        self.cuts: dict[int, int] = {}
        #: positions of the slaves of unplugged hot-connect groups (out of the line, neighbours joined)
        self.detached: set[int] = set()
        self._reached: list[Slave] = list(self.slaves)
        #: where a frame entering on the primary interface leaves (ring.PORT_A / PORT_B / LOST)
        self.exit_a = PORT_A
        #: the slaves a frame entering on the secondary interface reaches, where it leaves, the slave that turns it
        self._reached_b: list[Slave] = []
        self.exit_b = LOST
        self._turn_b: Slave | None = None
        #: :meth:`process` left PDI work for :meth:`after_frame`
        self._after_pending = False
        #: told of every frame served (None: nobody watches)
        self.observer: FrameObserver | None = None

        #: DC: when the frame being processed left the master (one time for the whole frame, as on a wire)
        self.frame_time = FrameTime()
        self._link()

    def _link(self) -> None:
        """The slaves a frame reaches from each end (ring.py): on a line, up to the first unplugged slave or open
        port, whose upstream neighbour closes its port and returns the frame (ESC automatic port loop-back); each
        ESC's DL status 0x0110 shows the links of its ports."""
        r = routes(len(self.slaves), redundant=self.redundant, cuts=self.cuts, unplugged=self.unplugged,
                   detached=self.detached)
        self._reached = [self.slaves[p] for p in r.a]
        self.exit_a = r.a_exit
        self._reached_b = [self.slaves[p] for p in r.b]
        self.exit_b = r.b_exit
        self._turn_b = self.slaves[r.b_turn] if r.b_turn >= 0 else None
        for p, slave in enumerate(self.slaves):
            slave.esc.set_downstream(r.downstream[p], r.links[p])
        # DC: when a frame reaches each slave of either route
        place_line([s.esc.clocks for s in self._reached], self.frame_time)
        if self._reached_b:
            place_line([s.esc.clocks for s in self._reached_b], self.frame_time)

    @property
    def reached(self) -> list[Slave]:
        """The slaves a frame entering on the primary interface reaches, in order."""
        return list(self._reached)

    @property
    def reached_secondary(self) -> list[Slave]:
        """The slaves a frame entering on the secondary interface reaches, in order (cable redundancy)."""
        return list(self._reached_b)

    def cut(self, gap: int) -> None:
        """Open gap ``gap`` (the cable into slave ``gap``'s port 0; ``len(slaves)``: the cable to the secondary
        interface): both ports lose their link, and close."""
        if not 0 <= gap <= len(self.slaves):
            raise SlavePositionError(f"no cable {gap} in a line of {len(self.slaves)} slaves")
        self.cuts[gap] = self.cuts.get(gap, 0) + 1
        self._link()

    def join(self, gap: int) -> None:
        """Undo one :meth:`cut` of ``gap`` (the link comes back once no fault holds it open)."""
        left = self.cuts.get(gap, 0) - 1
        if left > 0:
            self.cuts[gap] = left
        else:
            self.cuts.pop(gap, None)
        self._link()

    def set_redundant(self, redundant: bool) -> None:
        """Cable the last slave's port 1 to the master's secondary interface (or not)."""
        self.redundant = redundant
        self._link()

    def detach(self, positions: list[int]) -> None:
        """Unplug a hot-connect group: its slaves leave the line, the slaves around it are joined."""
        for p in positions:
            if not 0 <= p < len(self.slaves):
                raise SlavePositionError(f"no slave at position {p}")
        self.detached.update(positions)
        self._link()

    def attach(self, positions: list[int]) -> None:
        """Plug a hot-connect group back in: its slaves power on (AL status INIT, registers reset)."""
        back = [p for p in positions if p in self.detached]
        self.detached.difference_update(back)
        for p in back:
            self.slaves[p].esc.power_cycle()
        self._link()

    def unplug(self, position: int) -> None:
        """Pull a slave out of the line: it and every slave behind it stop answering (the working
        counter of every datagram for them drops); on a redundant ring the slaves behind it answer through
        the secondary interface (ring.py)."""
        if not 0 <= position < len(self.slaves):
            raise SlavePositionError(f"no slave at position {position}")
        self.unplugged.add(position)
        self._link()

    def replug(self, position: int) -> None:
        """Plug a slave back in: it powers on (AL status INIT, registers reset) and the line
        behind it answers again (those slaves kept their state)."""
        if position in self.unplugged:
            self.unplugged.discard(position)
            self.slaves[position].esc.power_cycle()
            self._link()

    def process(self, frame: bytearray, *, defer: bool = False) -> bool:
        """Execute every datagram on every slave in place; False for a dropped (bad) frame, or
        when the first slave is unplugged (no link: the frame never comes back).

        ``defer``: leave the applications' work after the frame (:meth:`after_frame`) to the caller,
        who sends the frame back first and calls it once no other frame waits (the second frame of a
        split process image is then answered without waiting for the first one's applications; a slave's
        firmware reads the SyncManager's newest buffer whenever it gets to it). Without ``defer`` the work
        runs before this returns, the work a deferring caller left first."""
        if self._after_pending and not defer:
            self.after_frame()
        if self.exit_a < 0:     # ring.LOST: no link on the primary side
            return False
        parsed = self._parse(frame)
        if parsed is None:
            self.stats.bad_frames += 1
            if self._reached:
                mem = self._reached[0].esc.mem
                mem[REG_RX_ERROR] = min(0xFF, mem[REG_RX_ERROR] + 1)
            return False
        self.stats.frames += 1
        self.stats.datagrams += len(parsed)
        frame_time = self.frame_time
        frame_time.t = -1.0               # stamped by the frame's first DC access
        for slave in self._reached:
            esc = slave.esc
            for pos, cmd, dlen in parsed:
                try:
                    events = esc.process_datagram(frame, pos, cmd, dlen)  # a native call (no bound-method alias)
                    if events is not None:  # Slave.process_datagram, inlined: most datagrams raise none
                        slave.serve_events(events)
                except Exception as exc:  # isolation boundary: one datagram never costs the frame
                    self._datagram_error(esc, cmd, exc)
        frame_time.t = -1.0
        if len(frame) > ETH_HEADER_LEN:
            frame[6] |= 0x02  # the ESC marks the source MAC as locally administered on the way back
        if self.observer is not None:
            self.observer.frame_served(frame, parsed)
        if defer:
            self._after_pending = True
        else:
            self.after_frame()
        return True

    def after_frame(self) -> None:
        """The PDI work the last frame left (:meth:`Slave.after_frame` of each slave it reached, in line
        order); call it once the frame is on its way back. One raising application costs only its own
        delivery (counted and logged as a datagram error, see the module docstring)."""
        self._after_pending = False
        for slave in self._reached:
            if slave.outputs_pending or slave.inputs_read_pending:
                try:
                    slave.after_frame()
                except Exception as exc:  # isolation boundary, as for a datagram
                    self._datagram_error(slave.esc, -1, exc)
        for slave in self._reached_b:   # empty unless a frame may enter on the secondary interface
            if slave.outputs_pending or slave.inputs_read_pending:
                try:
                    slave.after_frame()
                except Exception as exc:  # isolation boundary, as for a datagram
                    self._datagram_error(slave.esc, -1, exc)

    def process_secondary(self, frame: bytearray, *, defer: bool = False) -> int:
        """A frame entering on the secondary interface (cable redundancy, ring.py): executed in place by the
        slaves behind the first open gap from that end; returns where it leaves (ring.PORT_A: it passed the
        whole ring unprocessed, PORT_B, or LOST: not sent back)."""
        if self._after_pending and not defer:
            self.after_frame()
        if self.exit_b == LOST:
            return LOST
        parsed = self._parse(frame)
        if parsed is None:
            self.stats.bad_frames += 1
            return LOST
        if self._turn_b is not None:
            first = parsed[0][0] + 7    # high byte of the first datagram's length field
            if frame[first] & _CIRCULATING:     # circulated once already: the ESC destroys it
                return LOST
            frame[first] |= _CIRCULATING
        self.stats.frames += 1
        self.stats.datagrams += len(parsed)
        frame_time = self.frame_time
        frame_time.t = -1.0               # stamped by the frame's first DC access, as in process
        for slave in self._reached_b:
            esc = slave.esc
            for pos, cmd, dlen in parsed:
                try:
                    events = esc.process_datagram(frame, pos, cmd, dlen)
                    if events is not None:
                        slave.serve_events(events)
                except Exception as exc:  # isolation boundary, as in process
                    self._datagram_error(esc, cmd, exc)
        frame_time.t = -1.0
        if len(frame) > ETH_HEADER_LEN:
            frame[6] |= 0x02
        if defer:
            self._after_pending = True
        else:
            self.after_frame()
        return self.exit_b

    def _datagram_error(self, esc: Esc, cmd: int, exc: Exception) -> None:
        esc.stats.datagram_errors += 1
        n = self.stats.datagram_errors = self.stats.datagram_errors + 1
        position = next((i for i, s in enumerate(self.slaves) if s.esc is esc), -1)
        text = f"slave {position} cmd {cmd}: {type(exc).__name__}: {' '.join(str(exc).split())}"
        self.stats.errors.append(text)
        if n <= LOG_FIRST or n % LOG_EVERY == 0:
            _log.error("ethercat segment: datagram raised (isolated, %d so far): %s", n, text)

    @staticmethod
    def _parse(frame: bytearray) -> list[tuple[int, int, int]] | None:
        n = len(frame)
        if n < ETH_HEADER_LEN + 2 or _BE16.unpack_from(frame, 12)[0] != ETHERTYPE_ETHERCAT:
            return None
        hdr = _U16.unpack_from(frame, ETH_HEADER_LEN)[0]
        if hdr >> 12 != 1:
            return None
        end = ETH_HEADER_LEN + 2 + (hdr & LEN_MASK)
        if end > n:
            return None
        pos = ETH_HEADER_LEN + 2
        out: list[tuple[int, int, int]] = []
        while True:
            if pos + 12 > end:
                return None
            cmd, flags = _DG_HDR.unpack_from(frame, pos)
            dlen = flags & LEN_MASK
            if pos + 12 + dlen > end or cmd > 14:
                return None
            out.append((pos, cmd, dlen))
            pos += 12 + dlen
            if not flags & MORE:
                return out
