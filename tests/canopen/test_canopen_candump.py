"""The can-utils text forms (bus/candump.py, bus/errorframe.py): golden vectors from can-utils' own
documentation (lib.h comments, candump's help text), byte for byte."""

from __future__ import annotations

import datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.bus.candump import (
    CandumpSyntaxError,
    IdTable,
    Timestamps,
    line,
    long_error_frame,
    long_frame,
    parse_cansend,
    parse_filters,
)
from gatewaylab.bus.errorframe import ErrorFrame, bus_error, describe, state_change, summary
from gatewaylab.bus.frame import CanFrame


@pytest.mark.parametrize("frame, text", [
    (CanFrame(0x12345678, b"\x11\x22\x33", extended=True), "12345678   [3]  11 22 33"),
    (CanFrame(0x12345678, b"", extended=True, rtr=True), "12345678   [0]  remote request"),
    (CanFrame(0x14B0DC51, bytes.fromhex("4A94E82AEC585562"), extended=True),
     "14B0DC51   [8]  4A 94 E8 2A EC 58 55 62"),
    (CanFrame(0x12345678, b"\x11\x22\x33", extended=True, fd=True), "12345678  [03]  11 22 33"),
    (CanFrame(0x123, b"\x11\x22\x33"), "123   [3]  11 22 33"),
])
def test_long_form_is_lib_h_snprintf_long_canframe(frame: CanFrame, text: str) -> None:
    """can-utils lib.h, snprintf_long_canframe: the examples of its comment."""
    assert long_frame(frame) == text


def test_sff_ids_are_indented_once_an_eff_frame_was_seen() -> None:
    """lib.h: '123   [3]  11 22 33 -> CANLIB_VIEW_INDENT_SFF == 0', '     123   [3]  11 22 33 -> set'."""
    assert long_frame(CanFrame(0x123, b"\x11\x22\x33"), indent_sff=True) == "     123   [3]  11 22 33"


def test_error_frame_long_form_and_its_minus_e_text() -> None:
    """lib.h: '20001111   [7]  C6 23 7B 32 69 98 3C      ERRORFRAME -> (CAN_ERR_FLAG set)'; the -e lines
    are lib.c snprintf_can_error_frame's class names with their details."""
    assert long_error_frame(ErrorFrame(0x1111, bytes.fromhex("C6237B3269983C"))) == \
        "20001111   [7]  C6 23 7B 32 69 98 3C      ERRORFRAME"
    crc = bus_error("crc", False, 0, 1)
    assert long_error_frame(crc) == "20000288   [8]  00 00 00 08 00 00 00 01   ERRORFRAME"
    assert describe(crc) == "protocol-violation{{}{crc-sequence}}\n\tbus-error\n\terror-counter-tx-rx{{0}{1}}"
    assert describe(bus_error("stuff", True, 8, 0), ", ") == \
        "protocol-violation{{bit-stuffing-error,error-on-tx}{}}, bus-error, error-counter-tx-rx{{8}{0}}"
    assert describe(state_change("error-active", "bus-off", 256, 0)) == "bus-off\n\terror-counter-tx-rx{{255}{0}}"
    assert summary(state_change("bus-off", "error-active", 0, 0)).startswith("controller restarted after bus-off")
    assert summary(bus_error("ack", True, 8, 0)) == "error frame: no acknowledgement (ACK error), TEC 8 REC 0"


def test_candump_line_and_timestamps() -> None:
    """candump.c sprint_timestamp: '(%010llu.%06llu) ' absolute, '(%03llu.%06llu) ' delta/zero, and the
    line ' ' + stamp + ' ' + interface + '  ' + frame."""
    a, d, z = Timestamps("a"), Timestamps("d"), Timestamps("z")
    assert a.text(1345212884.318850) == "(1345212884.318850) "
    assert [d.text(t) for t in (100.0, 100.5, 100.75)] == ["(000.000000) ", "(000.500000) ", "(000.250000) "]
    assert [z.text(t) for t in (100.0, 100.5, 112.75)] == ["(000.000000) ", "(000.500000) ", "(012.750000) "]
    assert Timestamps("A", datetime.UTC).text(0.25) == "(1970-01-01 00:00:00.250000) "
    assert Timestamps(None).text(5.0) == ""
    body = long_frame(CanFrame(0x123, b"\x11"))
    assert line(body, "can0") == "  can0  123   [1]  11"
    assert line(body, "can0", a.text(1345212884.318850)) == " (1345212884.318850)  can0  123   [1]  11"
    with pytest.raises(CandumpSyntaxError):
        Timestamps("x")


@pytest.mark.parametrize("spec, frames, passes", [
    # candump --help: "vcan2,123:7FF (matches CAN ID 123 - including EFF and RTR frames)"
    ("123:7FF", [CanFrame(0x123), CanFrame(0x123, extended=True), CanFrame(0x123, rtr=True)], True),
    ("123:7FF", [CanFrame(0x124), CanFrame(0x523)], False),
    # "123:C00007FF (matches CAN ID 123 - only SFF and non-RTR frames)"
    ("123:C00007FF", [CanFrame(0x123, b"\x01")], True),
    ("123:C00007FF", [CanFrame(0x123, extended=True), CanFrame(0x123, rtr=True)], False),
    # "12345678:DFFFFFFF (match only for extended CAN ID 12345678)"
    ("12345678:DFFFFFFF", [CanFrame(0x12345678, extended=True)], True),
    ("12345678:DFFFFFFF", [CanFrame(0x678), CanFrame(0x12345679, extended=True)], False),
    # "<can_id>~<can_mask> (matches when <received_can_id> & mask != can_id & mask)"
    ("400~7F0", [CanFrame(0x123), CanFrame(0x410)], True),
    ("400~7F0", [CanFrame(0x400), CanFrame(0x40F)], False),
    # "-l any,0~0,#FFFFFFFF (log only error frames but no(!) data frames)"
    ("0~0,#FFFFFFFF", [CanFrame(0x000), CanFrame(0x7FF)], False),
    # "Without any given filter all data frames are received ('0:0' default filter)"
    ("0:0", [CanFrame(0x1), CanFrame(0x1FFFFFFF, extended=True)], True),
    # several filters: any one; joined ('j'): all
    ("100:7F0,200:7F0", [CanFrame(0x105), CanFrame(0x20F)], True),
    ("100:700,10:F0,j", [CanFrame(0x115)], True),
    ("100:700,10:F0,j", [CanFrame(0x125), CanFrame(0x215)], False),
])
def test_filters_are_candumps(spec: str, frames: list[CanFrame], passes: bool) -> None:
    """candump --help, Filters, and its examples (the kernel's rule on SocketCAN can_ids)."""
    fs = parse_filters(spec)
    assert [fs.accepts(f) for f in frames] == [passes] * len(frames)


def test_error_mask_selects_error_classes() -> None:
    """'#<error_mask> (set error frame filter, see include/linux/can/error.h)': class bits."""
    assert parse_filters("#FFFFFFFF").accepts_error(bus_error("ack", True, 8, 0))
    assert not parse_filters("#00000040").accepts_error(bus_error("ack", True, 8, 0))
    assert parse_filters("#00000040").accepts_error(state_change("error-passive", "bus-off", 256, 0))
    assert not parse_filters("123:7FF").accepts_error(bus_error("crc", False, 0, 1))
    assert parse_filters(["123:7FF", "#FF"]).err_mask == 0xFF


@pytest.mark.parametrize("bad", ["", "123", "123:", "xyz:7FF", "123:7FF:1", "#", "#xyz", "k", "123456789:7FF"])
def test_bad_filters_are_usage_errors(bad: str) -> None:
    with pytest.raises(CandumpSyntaxError, match="filter"):
        parse_filters(bad)


@pytest.mark.parametrize("text, frame", [
    ("123#", CanFrame(0x123)),
    ("12345678#", CanFrame(0x12345678, extended=True)),
    ("123#R", CanFrame(0x123, rtr=True)),
    ("123#R0", CanFrame(0x123, rtr=True)),
    ("123#R7", CanFrame(0x123, rtr=True, dlc=7)),
    ("7A1#r", CanFrame(0x7A1, rtr=True)),
    ("123#00", CanFrame(0x123, b"\x00")),
    ("123#1122334455667788", CanFrame(0x123, bytes.fromhex("1122334455667788"))),
    ("123#11.22.33.44.55.66.77.88", CanFrame(0x123, bytes.fromhex("1122334455667788"))),
    ("123#11.2233.44556677.88", CanFrame(0x123, bytes.fromhex("1122334455667788"))),
    ("123##0112233", CanFrame(0x123, bytes.fromhex("112233"), fd=True)),
    ("123##1112233", CanFrame(0x123, bytes.fromhex("112233"), fd=True, brs=True)),
    ("123##2112233", CanFrame(0x123, bytes.fromhex("112233"), fd=True, esi=True)),
    ("123##3", CanFrame(0x123, b"", fd=True, brs=True, esi=True)),
    ("12345678#R5", CanFrame(0x12345678, extended=True, rtr=True, dlc=5)),
    ("123#DEADBEEF", CanFrame(0x123, bytes.fromhex("DEADBEEF"))),
    # cansend.c: "ensure discrete CAN FD length values 0..8, 12, 16, 20, 24, 32, 64" (zero padding)
    ("123##0" + "11" * 9, CanFrame(0x123, b"\x11" * 9 + bytes(3), fd=True)),
])
def test_cansend_syntax_is_lib_h_parse_canframe(text: str, frame: CanFrame) -> None:
    """can-utils lib.h, parse_canframe: the examples of its comment."""
    assert parse_cansend(text) == frame


@pytest.mark.parametrize("bad, why", [
    ("123", "no '#'"), ("12#11", "digits"), ("1234#11", "digits"), ("800#11", "at most 7FF"),
    ("32345678#112233", "CAN_ERR_FLAG"), ("123#123", "odd number"), ("123#GG", "not hexadecimal"),
    ("123#112233445566778899", "at most 8"), ("123#R9", "remote frame"), ("123##", "flags nibble"),
("123#1122334455667788_E", "raw DLC"),
])
def test_bad_frames_are_usage_errors_saying_why(bad: str, why: str) -> None:
    with pytest.raises(CandumpSyntaxError, match=why):
        parse_cansend(bad)


@given(st.text(max_size=40))
def test_any_text_gives_a_frame_or_a_usage_error(text: str) -> None:
    """Only usage errors come out of the parsers (DEVELOPERS.md, every parser)."""
    for parse in (parse_cansend, parse_filters):
        try:
            parse(text)
        except CandumpSyntaxError:
            pass


@given(st.from_regex(r"[0-9A-Fa-f]{3}#([0-9A-Fa-f]{2}){0,8}|[0-9A-Fa-f]{8}##[0-3]([0-9A-Fa-f]{2}){0,12}",
                     fullmatch=True))
def test_compact_form_round_trips(text: str) -> None:
    """A frame parsed from cansend's syntax prints back in it (CanFrame.__str__, upper-case)."""
    try:
        frame = parse_cansend(text)
    except CandumpSyntaxError:
        return     # an id out of range
    data = text.split("#")[-1][1 if frame.fd else 0:]
    if len(frame.data) == len(data) // 2:        # not padded to a CAN FD length
        assert str(frame) == text.upper()


def test_viewer_table_counts_and_periods() -> None:
    """can.viewer: per identifier its count, the time between its last two frames and its last data."""
    table = IdTable()
    table.feed(CanFrame(0x200, b"\x01"), 1.0)
    table.feed(CanFrame(0x100, b"\x02"), 1.0)
    table.feed(CanFrame(0x200, b"\x03"), 1.01)
    table.feed(CanFrame(0x200, b"\x04"), 1.03)
    rows = table.sorted_rows()
    assert [(r.frame.can_id, r.count, r.frame.data) for r in rows] == [(0x100, 1, b"\x02"), (0x200, 3, b"\x04")]
    assert rows[1].period == pytest.approx(0.02)
    assert table.lines(2.0)[2].split() == ["3", "20.0", "0.97", "200", "[1]", "04"]
