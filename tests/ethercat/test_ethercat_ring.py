"""Ports, cable redundancy and hot-connect groups on a simulated clock (ethercat/ring.py, Segment.cut / detach).

ET1100 data sheet, "Frame processing" and "Loop control": a frame entering port 0 is processed and leaves by port 1;
one entering port 1 is forwarded to port 0 unprocessed; a port without a link is closed and loops the frame back.
Register 0x0110 (DL status): bits 4-7 physical link port 0-3, bit 8+2p loop port p closed, bit 9+2p communication
on port p. ETG.1000.4 cable redundancy: with the ring closed, the primary frame passes every slave and arrives on
the secondary port; with a break, the slaves before it answer through the primary port and those after it
through the secondary one. SOEM's ``ecx_waitinframe_red`` (nicdrv.c) is the master side replayed here.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import pytest
from ethercat_fixtures import make_segment

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.ring import LOST, PORT_A, PORT_B, routes
from gatewaylab.ethercat.segment import Segment

PRIMARY_SRC = b"\x01\x01\x01\x01\x01\x01"      # SOEM's priMAC
SECONDARY_SRC = b"\x04\x04\x04\x04\x04\x04"    # SOEM's secMAC


def dl_status(segment: Segment, position: int) -> int:
    value: int = struct.unpack_from("<H", segment.slaves[position].esc.mem, 0x0110)[0]
    return value


def brd(index: int = 1) -> Datagram:
    return Datagram.physical(Command.BRD, index, 0, 0x0000, b"\0\0")


def red_exchange(segment: Segment, datagrams: Sequence[Datagram]) -> tuple[Datagram, ...] | None:
    """One exchange of a redundant master as SOEM's ecx_outframe_red / ecx_waitinframe_red do it: the frame on
    the primary port, a dummy BRD on the secondary one; frames are told apart by their source MAC; a frame that
    came back on its own port (a break) is sent again through the secondary port. None: no answer."""
    frame = bytearray(encode_frame(Frame(tuple(datagrams), src=PRIMARY_SRC)))
    dummy = bytearray(encode_frame(Frame((brd(datagrams[0].index),), src=SECONDARY_SRC)))
    arrived: dict[int, bytearray] = {}
    if segment.process(frame):
        arrived[segment.exit_a] = frame
    out = segment.process_secondary(dummy)
    if out != LOST:
        arrived[out] = dummy
    def sent_by(buf: bytearray | None) -> str:
        return "" if buf is None else ("prim" if buf[8:10] == PRIMARY_SRC[2:4] else "sec")
    prim, sec = sent_by(arrived.get(PORT_A)), sent_by(arrived.get(PORT_B))
    if prim == "sec" and sec == "prim":      # the ring is closed
        return decode_frame(arrived[PORT_B]).datagrams
    if sec == "sec" and prim in ("", "prim"):
        again = arrived[PORT_A] if prim == "prim" else bytearray(encode_frame(Frame(tuple(datagrams),
                                                                                     src=PRIMARY_SRC)))
        if segment.process_secondary(again) == PORT_B:
            return decode_frame(again).datagrams
        return None
    return decode_frame(arrived[PORT_A]).datagrams if prim == "prim" else None


@pytest.fixture
def ring(clock: SimulatedClock) -> Segment:
    segment = make_segment(clock, 4)
    segment.set_redundant(True)
    return segment


def test_routes_of_a_line_a_ring_and_a_break() -> None:
    """A line returns every frame on A; a closed ring passes the primary frame on to B and the secondary frame
    unprocessed to A; a break after slave 1 splits the slaves between the two ports."""
    line = routes(4)
    assert (line.a, line.a_exit, line.b_exit) == ((0, 1, 2, 3), PORT_A, LOST)
    assert line.links == (0b11, 0b11, 0b11, 0b01)
    ring = routes(4, redundant=True)
    assert (ring.a, ring.a_exit, ring.b, ring.b_exit) == ((0, 1, 2, 3), PORT_B, (), PORT_A)
    assert ring.links == (0b11,) * 4
    broken = routes(4, redundant=True, cuts={2})
    assert (broken.a, broken.a_exit, broken.b, broken.b_exit, broken.b_turn) == ((0, 1), PORT_A, (2, 3), PORT_B, 2)
    assert broken.links == (0b11, 0b01, 0b10, 0b11) and broken.downstream == (1, 0, 1, 0)
    primary_cut = routes(4, redundant=True, cuts={0})
    assert (primary_cut.a_exit, primary_cut.b) == (LOST, (0, 1, 2, 3))


def test_routes_around_an_unplugged_slave_and_a_hot_connect_group() -> None:
    """An unplugged slave takes both its cables: a line ends before it, a ring reaches the slaves after it from B.
    A detached hot-connect group leaves the line joined around it (it hangs off a junction port)."""
    r = routes(5, redundant=True, unplugged={2})
    assert (r.a, r.b, r.links[2]) == ((0, 1), (3, 4), 0)
    hot = routes(5, detached={1, 2})
    assert (hot.a, hot.a_exit, hot.links[1], hot.links[3]) == ((0, 3, 4), PORT_A, 0, 0b11)


def test_closed_ring_returns_the_processed_frame_on_the_secondary_port(ring: Segment) -> None:
    """Closed ring: the frame sent on A is counted by all 4 slaves and leaves on B; the dummy sent on B arrives
    on A untouched (no slave processes a frame entering port 1)."""
    frame = bytearray(encode_frame(Frame((brd(),))))
    assert ring.process(frame) and ring.exit_a == PORT_B
    assert decode_frame(frame).datagrams[0].wkc == 4
    dummy = bytearray(encode_frame(Frame((brd(),))))
    assert ring.process_secondary(dummy) == PORT_A
    assert decode_frame(dummy).datagrams[0].wkc == 0
    assert all(dl_status(ring, p) & 0x0F30 == 0x0A30 for p in range(4))    # both ports: link, open, communication


def test_a_redundant_master_keeps_its_working_counter_across_a_break_and_heal(ring: Segment) -> None:
    """Break after slave 1: the primary frame returns on A counted by slaves 0-1, the resent one by 2-3 (and
    it carries the circulating bit slave 2's closed port 0 set); the sum is the full count, as with the ring
    closed and after it is mended."""
    assert red_exchange(ring, [brd()])[0].wkc == 4    # type: ignore[index]
    ring.cut(2)
    out = red_exchange(ring, [brd()])
    assert out is not None and out[0].wkc == 4 and out[0].circulating
    ring.join(2)
    assert red_exchange(ring, [brd()])[0].wkc == 4    # type: ignore[index]
    assert ring.exit_a == PORT_B


def test_break_between_the_master_and_the_first_slave(ring: Segment) -> None:
    """A cut of the primary cable: nothing comes back on A, every slave answers through B."""
    ring.cut(0)
    frame = bytearray(encode_frame(Frame((brd(),))))
    assert not ring.process(frame)
    assert red_exchange(ring, [brd()])[0].wkc == 4    # type: ignore[index]


def test_dl_status_shows_the_open_port_and_comes_back(segment: Segment) -> None:
    """ET1100 0x0110 after the cable between slave 0 and 1 loses its link: slave 0's port 1 has no link and is
    closed (0x0400, no 0x0020/0x0800), slave 1's port 0 too (0x0100, no 0x0010/0x0200); a BRD counts only slave 0
    (a line: the slaves behind the port vanish). Joined again, every value is what it was."""
    before = [dl_status(segment, p) for p in range(3)]
    assert before[0] & 0x0F30 == 0x0A30 and before[2] & 0x0F30 == 0x0610     # the last slave's port 1 is closed
    segment.cut(1)
    assert dl_status(segment, 0) & 0x0F30 == 0x0610
    assert dl_status(segment, 1) & 0x0F30 == 0x0920
    frame = bytearray(encode_frame(Frame((brd(),))))
    assert segment.process(frame) and decode_frame(frame).datagrams[0].wkc == 1
    segment.join(1)
    assert [dl_status(segment, p) for p in range(3)] == before


def test_a_second_pass_through_a_closed_port_0_destroys_the_frame(ring: Segment) -> None:
    """ET1100 'Circulating frames': a frame arriving at a closed port 0 with the circulating bit set is destroyed."""
    ring.cut(2)
    frame = bytearray(encode_frame(Frame((Datagram(Command.BRD, 1, 0, b"\0\0", circulating=True),))))
    assert ring.process_secondary(frame) == LOST


def test_hot_connect_group_leaves_the_line_joined_and_returns_in_init(clock: SimulatedClock) -> None:
    """A group of slaves 1-2 unplugged: the BRD count drops by 2 and slave 3 answers at auto-increment position 1;
    plugged in again, the group's slaves are in INIT with station address 0 (power-on), slave 3 kept its address."""
    segment = make_segment(clock, 4)
    for p in range(4):
        frame = bytearray(encode_frame(Frame((Datagram.physical(Command.APWR, 1, (-p) & 0xFFFF, 0x0010,
                                                                struct.pack("<H", 0x1001 + p)),))))
        assert segment.process(frame)
    segment.detach([1, 2])
    frame = bytearray(encode_frame(Frame((brd(), Datagram.physical(Command.APRD, 2, 0xFFFF, 0x0010, b"\0\0")))))
    assert segment.process(frame)
    answer = decode_frame(frame).datagrams
    assert answer[0].wkc == 2 and answer[1].data == struct.pack("<H", 0x1004)
    segment.attach([1, 2])
    assert [s.esc.station_address for s in segment.slaves] == [0x1001, 0, 0, 0x1004]
