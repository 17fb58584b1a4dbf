"""Which slaves a frame reaches, and where it leaves, for a line or a redundant ring of ET1100-class slaves.

Each slave uses ports 0 and 1 (ET1100 data sheet, "Frame processing": a frame entering port 0 goes through the
EtherCAT processing unit and leaves by port 1; a frame entering port 1 is forwarded to port 0 without being
processed; a port without a link is closed, and a closed port loops the frame back inside the ESC). Port 0 of
slave 0 is cabled to the master's primary interface (A); with a redundant master, port 1 of the last slave is
cabled to its secondary interface (B), closing the ring.

The cables are numbered by *gap*: gap ``p`` is the cable into slave ``p``'s port 0 (gap 0: from A), gap ``n``
the cable from the last slave to B. A gap is open (no link) when it is cut (a broken cable, an open port, a
ring break), when a slave on either side of it is unplugged, and gap ``n`` is open without a redundant master.
Slaves of an unplugged hot-connect group are *detached*: they leave the line and their neighbours are cabled to
each other (the group hangs off a junction port, as hot-connect groups do), so the slaves behind the group stay
reachable at positions one group shorter.

- A frame entering on A is processed by the slaves up to the first open gap behind it; there the slave closes its
  port 1 and the frame returns to A through the same slaves, unprocessed. With every gap closed it leaves on B.
- A frame entering on B passes the slaves backwards, unprocessed, down to the slave whose port 0 has no link: that
  port loops it back, it is processed from there to the last slave and leaves on B (ETG.1000.4 redundancy: the
  slaves behind a break answer through the secondary port); with no open gap it arrives on A unprocessed.
  The slave that turned it sets the circulating bit (ET1100 "Circulating frames": a frame that reaches a closed
  port 0 with the bit already set is destroyed).

Sans-I/O and pure: :func:`routes` is all of it; :class:`~gatewaylab.ethercat.segment.Segment` uses it whenever the
line changes.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Final

__all__ = ["LOST", "PORT_A", "PORT_B", "Routes", "routes"]

#: A frame's exit: back on the primary interface, out on the secondary one, or never (no link).
PORT_A: Final = 0
PORT_B: Final = 1
LOST: Final = -1


@dataclass(frozen=True, slots=True)
class Routes:
    """Where frames go in one state of the line; positions are the slaves' positions in the rig file."""

    #: slaves processing a frame that enters on A, in order
    a: tuple[int, ...]
    #: where that frame leaves (PORT_A, PORT_B, or LOST when A has no link)
    a_exit: int
    #: slaves processing a frame that enters on B, in order (empty without a break)
    b: tuple[int, ...]
    #: where that frame leaves (LOST without a redundant master or with no link on B)
    b_exit: int
    #: the slave whose closed port 0 turned the frame from B (-1: none)
    b_turn: int
    #: per position, the ports with a physical link (bit 0: port 0, bit 1: port 1); 0 for a slave out of the line
    links: tuple[int, ...]
    #: per position, the slaves that process a frame after this one does (the DC unit's delays)
    downstream: tuple[int, ...]


def routes(n: int, *, redundant: bool = False, cuts: Collection[int] = (), unplugged: Collection[int] = (),
           detached: Collection[int] = ()) -> Routes:
    """The routes of a line of ``n`` slaves (see the module docstring for the words)."""
    line = [p for p in range(n) if p not in detached]
    # open[j]: the cable into line[j]'s port 0 (j == len(line): the cable from the last slave to B) has no link
    gaps: list[bool] = []
    for j, p in enumerate(line):
        before_gone = j > 0 and line[j - 1] in unplugged
        gaps.append(p in cuts or p in unplugged or before_gone)
    gaps.append(not redundant or n in cuts or not line or line[-1] in unplugged)
    links = [0] * n
    for j, p in enumerate(line):
        if p not in unplugged:
            links[p] = (0 if gaps[j] else 1) | (0 if gaps[j + 1] else 2)
    downstream = [0] * n
    # from A
    a: list[int] = []
    a_exit = LOST
    if line and not gaps[0]:
        j = 0
        while j < len(line) and (j == 0 or not gaps[j]):
            a.append(line[j])
            j += 1
        a_exit = PORT_B if j == len(line) and not gaps[j] else PORT_A
    elif not line:
        a_exit = PORT_B if redundant and n not in cuts else PORT_A
    for i, p in enumerate(a):
        downstream[p] = len(a) - 1 - i
    # from B
    b: list[int] = []
    b_exit = LOST
    b_turn = -1
    if line and not gaps[-1]:
        turn = next((j for j in range(len(line) - 1, -1, -1) if gaps[j]), -1)
        if turn < 0:
            b_exit = PORT_A
        else:
            b = line[turn:]
            b_turn = line[turn]
            b_exit = PORT_B
    for i, p in enumerate(b):
        downstream[p] = len(b) - 1 - i
    return Routes(tuple(a), a_exit, tuple(b), b_exit, b_turn, tuple(links), tuple(downstream))
