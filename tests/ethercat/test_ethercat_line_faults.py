"""Faults of the line to the master (ethercat/line_faults.py) on a simulated segment, in process.

ETG.1000.4 (frame processing): a datagram's working counter counts the slaves that executed it; a frame
that does not reach slave 0 changes nothing; a reply lost (or corrupted: the master's NIC discards a frame
whose FCS is wrong, IEEE 802.3) on its way back leaves the slaves' work done. Frame layout: ETG.1000.4
'EtherCAT frame structure' (datagram header, data, 2-byte working counter).
"""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.ethercat.line_faults import (
    REORDER_HOLD_S,
    Kind,
    LineFault,
    LineFaults,
    Match,
    datagrams_of,
    parse_command,
)
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

REG_ALIAS = 0x0012     # configured station alias (ET1100 data sheet II 0x0012, ECAT read/write)


def _armed(segment: Segment, fault: LineFault) -> LineFaults:
    line = segment.line_faults = segment.line_faults or LineFaults()
    line.add(fault)
    return line


def _alias(master: Master, position: int) -> int:
    return int.from_bytes(master.fprd(master.slave(position).station, REG_ALIAS, 2), "little")


def _frame(*datagrams: Datagram) -> bytearray:
    return bytearray(encode_frame(Frame(tuple(datagrams))))


def test_lost_frames_never_reach_the_segment_and_the_count_ends_the_fault(master: Master, segment: Segment) -> None:
    """ec-lose 2: the next two frames are lost both ways (an FPWR among them changes nothing), the third
    comes back; the fault leaves the line by itself and says so once (on_end)."""
    ended: list[int] = []
    fault = LineFault(Kind.LOSE, count=2, on_end=lambda: ended.append(1))
    line = _armed(segment, fault)
    station = master.slave(0).station
    before = master.lost_frames
    with pytest.raises(TimeoutError_):
        master.fpwr(station, REG_ALIAS, (0x1234).to_bytes(2, "little"))
    with pytest.raises(TimeoutError_):
        master.fprd(station, REG_ALIAS, 2)
    assert master.lost_frames == before + 2 and ended == [1]
    assert not line.engaged and fault.details == {"hits": 2, "left": 0}
    assert _alias(master, 0) == 0                      # the lost write never reached the slave


def test_lost_replies_leave_the_slaves_work_done(master: Master, segment: Segment) -> None:
    """ec-lose 1 --replies: the FPWR is executed (the alias register holds the value) but its reply is lost."""
    _armed(segment, LineFault(Kind.LOSE_REPLY, count=1))
    with pytest.raises(TimeoutError_):
        master.fpwr(master.slave(1).station, REG_ALIAS, (0x0BEE).to_bytes(2, "little"))
    assert _alias(master, 1) == 0x0BEE


def test_corrupted_replies_are_processed_and_lost(master: Master, segment: Segment) -> None:
    """ec-corrupt 1: the slaves process the frame, the master's NIC drops the reply for its bad FCS."""
    line = _armed(segment, LineFault(Kind.CORRUPT, count=1))
    with pytest.raises(TimeoutError_):
        master.fpwr(master.slave(2).station, REG_ALIAS, (0x0042).to_bytes(2, "little"))
    assert _alias(master, 2) == 0x0042 and line.lost == 1


def test_filters_pick_the_frames_of_a_command_a_station_a_logical_range(master: Master, segment: Segment) -> None:
    """Only frames with a matching datagram are lost and counted: --cmd FPWR spares FPRD, --station spares
    the other slaves' datagrams."""
    s0, s1 = master.slave(0).station, master.slave(1).station
    fault = LineFault(Kind.LOSE, Match(frozenset({Command.FPWR}), station=s1), count=1)
    line = _armed(segment, fault)
    master.fprd(s1, REG_ALIAS, 2)                                   # FPRD: not the command
    master.fpwr(s0, REG_ALIAS, b"\x01\x00")                         # FPWR, another station
    with pytest.raises(TimeoutError_):
        master.fpwr(s1, REG_ALIAS, b"\x02\x00")
    assert not line.faults and _alias(master, 0) == 1 and _alias(master, 1) == 0


def test_logical_range_matches_overlapping_datagrams_only() -> None:
    """--logical START:END (END included) hits an LRW whose [address, address + length) overlaps it."""
    m = Match(logical=(0x100, 0x1FF))
    assert m.datagram(Command.LRW, 0x0F0, 0x20)          # 0xF0..0x10F overlaps
    assert m.datagram(Command.LRD, 0x1FF, 1)
    assert not m.datagram(Command.LRW, 0x200, 4)
    assert not m.datagram(Command.LRW, 0x0F0, 0x10)      # 0xF0..0xFF ends before
    assert not m.datagram(Command.FPRD, 0x150, 2)        # not a logical command


def test_wkc_offset_hits_exactly_n_datagrams(clock: SimulatedClock, segment: Segment) -> None:
    """ec-wkc 3 -n 2 --cmd LRW: the next two process data cycles read WKC + 3, then the true WKC again;
    other datagrams keep theirs."""
    m = Master(clock, segment)
    m.bring_up()
    good = m.exchange_process_data()
    assert good == m.expected_wkc
    line = _armed(segment, LineFault(Kind.WKC, Match(frozenset({Command.LRW})), count=2, offset=3))
    assert m.al_status(0)[0] is not None                  # an FPRD: not counted
    assert [m.exchange_process_data() for _ in range(4)] == [good + 3, good + 3, good, good]
    assert not line.faults


def test_wkc_offset_wraps_modulo_2_16() -> None:
    """The working counter is 16 bits (ETG.1000.4): an offset below 0 wraps."""
    seg = Segment([])
    fault = LineFault(Kind.WKC, count=1, offset=-1)
    line = _armed(seg, fault)
    frame = _frame(Datagram(Command.BRD, 1, 0, b"\0\0"))
    assert line.serve(seg, frame, 0.0)
    assert decode_frame(frame).datagrams[0].wkc == 0xFFFF


def test_delay_holds_replies_in_order_with_seeded_jitter(segment: Segment) -> None:
    """ec-delay: a reply leaves at its due time, never before, never ahead of an earlier one; the same
    seed gives the same jitter."""
    def dues(seed: int) -> list[float]:
        line = LineFaults()
        segment.line_faults = line
        line.add(LineFault(Kind.DELAY, delay_s=0.003, jitter_s=0.001, seed=seed))
        out = []
        for i in range(5):
            assert not line.serve(segment, _frame(Datagram(Command.BRD, i, 0x130, b"\0\0")), i * 0.0001)
            out.append(line.held[-1][0])
        return out
    a, b = dues(7), dues(7)
    assert a == b and a == sorted(a) and all(t >= 0.003 for t in a)
    line = segment.line_faults
    assert line is not None
    assert line.due(a[0] - 1e-9) == []
    first = line.due(a[0])
    assert first and decode_frame(first[0]).datagrams[0].index == 0
    rest = line.due(1.0)
    assert [decode_frame(r).datagrams[0].index for r in first + rest] == [0, 1, 2, 3, 4]
    assert line.engaged                                   # the delay stays until removed


def test_duplicate_and_reorder(segment: Segment) -> None:
    """ec-duplicate 1: the reply, then the same reply again. ec-reorder 1: reply A waits for reply B and
    follows it; without a next reply it leaves alone after REORDER_HOLD_S."""
    line = _armed(segment, LineFault(Kind.DUPLICATE, count=1))
    frame = _frame(Datagram(Command.BRD, 9, 0x130, b"\0\0"))
    assert line.serve(segment, frame, 0.0)
    assert line.due(0.0) == [bytes(frame)] and not line.engaged
    line.add(LineFault(Kind.REORDER, count=1))
    a, b = _frame(Datagram(Command.BRD, 1, 0x130, b"\0\0")), _frame(Datagram(Command.BRD, 2, 0x130, b"\0\0"))
    assert not line.serve(segment, a, 1.0)                # A held
    assert line.engaged and not line.faults               # the count is used up, A still waits for B
    assert line.serve(segment, b, 1.001)                  # B goes out ...
    assert line.due(1.001) == [bytes(a)]                  # ... and A after it
    line.add(LineFault(Kind.REORDER, count=1))
    assert not line.serve(segment, a, 2.0)
    assert line.due(2.0 + REORDER_HOLD_S / 2) == [] and line.due(2.0 + REORDER_HOLD_S) == [bytes(a)]


def test_link_down_passes_nothing_until_removed(master: Master, segment: Segment) -> None:
    """ec-link-down: no frame reaches the segment (nothing processed), none comes back; removed, the line
    answers again."""
    fault = LineFault(Kind.LINK_DOWN)
    line = _armed(segment, fault)
    for _ in range(3):
        with pytest.raises(TimeoutError_):
            master.fpwr(master.slave(0).station, REG_ALIAS, b"\x05\x00")
    line.remove(fault)
    assert _alias(master, 0) == 0 and not line.engaged


def test_in_process_master_loses_held_replies(master: Master, segment: Segment) -> None:
    """The in-process master takes a frame's reply at once or never: a delayed reply is lost to it."""
    line = _armed(segment, LineFault(Kind.DELAY, delay_s=0.0001))
    with pytest.raises(TimeoutError_):
        master.fprd(master.slave(0).station, REG_ALIAS, 2)
    assert not line.held


def test_datagrams_of_golden_frame() -> None:
    """Offsets, commands, addresses and lengths as encode_frame lays them out (ETG.1000.4)."""
    raw = encode_frame(Frame((Datagram(Command.LRW, 1, 0x00010000, bytes(8)),
                              Datagram.physical(Command.FPRD, 2, 0x1001, 0x0130, bytes(2)))))
    assert datagrams_of(raw) == [(16, Command.LRW, 0x00010000, 8), (16 + 20, Command.FPRD, 0x1001 | 0x0130 << 16, 2)]
    assert datagrams_of(raw[:30]) is None and datagrams_of(b"") is None


@given(st.binary(max_size=120))
def test_datagrams_of_never_raises(raw: bytes) -> None:
    """Any bytes: None or datagrams that lie inside the frame."""
    out = datagrams_of(raw)
    assert out is None or all(pos + 12 + n <= len(raw) for pos, _c, _a, n in out)


def test_parse_command_names_and_numbers() -> None:
    """Commands by name (any case) or number, as ETG.1000.4 numbers them; others refused."""
    assert parse_command("lrw") == 12 and parse_command("0x7") == Command.BRD and parse_command(5) == 5
    with pytest.raises(EtherCATConfigError):
        parse_command("LRX")
    with pytest.raises(EtherCATConfigError):
        parse_command(15)
