"""What a scenario waits for on an EtherCAT line, read from the frames the segment serves: a slave that
reaches an AL state, the N-th process-data cycle, an SDO request to an index.

:class:`MilestoneWatch` is the segment's :class:`~gatewaylab.ethercat.segment.FrameObserver` while at least
one milestone is pending (sans-I/O: frames in, callbacks out; no clock). It detaches itself once every
milestone has been met, so a line with nothing left to wait for pays nothing more than the one ``None``
check of :meth:`Segment.process`.

Definitions (docs/faults.md "Scenarios"):

* a **cycle** is a frame the segment served (well formed, reaching at least the first slave) that holds at
  least one logical process-data datagram (LRD, LWR or LRW; ETG.1000.4 table "EtherCAT command types"),
  whatever its working counter; cycle N is the N-th such frame since the watch was made;
* a **state** is reached when the slave's AL status register (0x0130, ETG.1000.6 AL status) shows it after a
  frame (or when the watch is armed);
* an **SDO to an index** is a mailbox write (APWR / FPWR addressed to the slave, at the start of its
  SyncManager 0, working counter >= 1) carrying a CoE SDO request (ETG.1000.6 5.6.2: mailbox type 3, CoE
  service 2) whose command is an initiate download or upload (ccs 1 or 2, complete access included) of that
  index. Segments of a transfer carry no index and do not count.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Final

from gatewaylab.ethercat.datagram import Command
from gatewaylab.ethercat.esc import REG_STATION_ADDRESS, AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave

__all__ = ["PROCESS_DATA_COMMANDS", "MilestoneWatch", "sdo_index"]

#: The datagram commands a cycle is made of.
PROCESS_DATA_COMMANDS: Final = frozenset({Command.LRD, Command.LWR, Command.LRW})
_U16: Final = struct.Struct("<H")
_MBX_HEADER: Final = 6          # length, address, channel/priority, type/counter
_MBX_TYPE_COE: Final = 3
_COE_SDO_REQUEST: Final = 2
_SDO_MIN: Final = _MBX_HEADER + 2 + 4     # + CoE header + command, index, subindex


def sdo_index(data: bytes | bytearray | memoryview) -> int | None:
    """The object index of a mailbox's CoE SDO initiate request (download or upload), else None."""
    if len(data) < _SDO_MIN or data[5] & 0x0F != _MBX_TYPE_COE:
        return None
    if _U16.unpack_from(data, _MBX_HEADER)[0] >> 12 != _COE_SDO_REQUEST:
        return None
    ccs = data[_MBX_HEADER + 2] >> 5
    if ccs not in (1, 2):
        return None
    index: int = _U16.unpack_from(data, _MBX_HEADER + 3)[0]
    return index


class MilestoneWatch:
    """Callbacks for milestones of one segment's frames; each callback runs once, after the frame that met
    it (in the order the milestones were added)."""

    def __init__(self, segment: Segment) -> None:
        self.segment = segment
        #: process-data cycles served since the watch was made
        self.cycles = 0
        self._states: list[tuple[Slave, AlState, Callable[[], None]]] = []
        self._cycle_waits: list[tuple[int, Callable[[], None]]] = []
        self._sdos: list[tuple[Slave, int, Callable[[], None]]] = []

    # -- what to wait for ------------------------------------------------------------------------------
    def on_state(self, slave: Slave, state: AlState, callback: Callable[[], None]) -> None:
        """Call ``callback`` once ``slave`` shows AL state ``state``."""
        self._states.append((slave, state, callback))

    def on_cycles(self, count: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` after the ``count``-th process-data cycle."""
        self._cycle_waits.append((count, callback))

    def on_sdo(self, slave: Slave, index: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` after the first SDO request of ``slave`` to object ``index``."""
        self._sdos.append((slave, index, callback))

    @property
    def pending(self) -> int:
        """Milestones not met yet."""
        return len(self._states) + len(self._cycle_waits) + len(self._sdos)

    def attach(self) -> None:
        """Become the segment's observer (when anything is pending) and check the states once now."""
        if self.pending:
            self.segment.observer = self
        self._run(self._met_states())
        self._detach_when_done()

    def detach(self) -> None:
        """Stop watching (the rig closes)."""
        if self.segment.observer is self:
            self.segment.observer = None

    # -- the frame path ---------------------------------------------------------------------------------
    def frame_served(self, frame: bytearray, datagrams: list[tuple[int, int, int]]) -> None:
        """:class:`~gatewaylab.ethercat.segment.FrameObserver`: count the cycle, look for SDO requests and
        states, then run what was met."""
        due: list[Callable[[], None]] = []
        if any(cmd in PROCESS_DATA_COMMANDS for _, cmd, _ in datagrams):
            self.cycles += 1
            if self._cycle_waits:
                keep = []
                for entry in self._cycle_waits:
                    if entry[0] <= self.cycles:
                        due.append(entry[1])
                    else:
                        keep.append(entry)
                self._cycle_waits = keep
        if self._sdos:
            due += self._met_sdos(frame, datagrams)
        if self._states:
            due += self._met_states()
        self._run(due)
        self._detach_when_done()

    def _met_states(self) -> list[Callable[[], None]]:
        due: list[Callable[[], None]] = []
        keep = []
        for entry in self._states:
            slave, state, callback = entry
            if slave.esc.al_status & 0x0F == state:
                due.append(callback)
            else:
                keep.append(entry)
        self._states = keep
        return due

    def _met_sdos(self, frame: bytearray, datagrams: list[tuple[int, int, int]]) -> list[Callable[[], None]]:
        due: list[Callable[[], None]] = []
        for pos, cmd, dlen in datagrams:
            if cmd not in (Command.FPWR, Command.APWR) or dlen < _SDO_MIN:
                continue
            if _U16.unpack_from(frame, pos + 10 + dlen)[0] == 0:      # nobody took it
                continue
            adp, ado = struct.unpack_from("<HH", frame, pos + 2)
            index = sdo_index(memoryview(frame)[pos + 10:pos + 10 + dlen])
            if index is None:
                continue
            keep = []
            for entry in self._sdos:
                slave, want, callback = entry
                if want == index and ado == slave.esc.sm_config(0).start and self._addressed(slave, cmd, adp):
                    due.append(callback)
                else:
                    keep.append(entry)
            self._sdos = keep
        return due

    def _addressed(self, slave: Slave, cmd: int, adp: int) -> bool:
        """Whether a physical write with ``adp`` is for ``slave`` (by configured address or position)."""
        if cmd == Command.FPWR:
            station: int = _U16.unpack_from(slave.esc.mem, REG_STATION_ADDRESS)[0]
            return adp == station
        return slave in self.segment.slaves and (-adp) & 0xFFFF == self.segment.slaves.index(slave)

    @staticmethod
    def _run(due: list[Callable[[], None]]) -> None:
        for callback in due:
            callback()

    def _detach_when_done(self) -> None:
        if not self.pending:
            self.detach()
