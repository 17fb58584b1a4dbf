"""Issue 13 part 3 'Side-by-side comparison', the pure part: two recorded traces in, "frames only in
one trace, order differences, payload differences, and the latency distributions (master -> CAN
and CAN -> master) per gateway" out; on hand-made traces, no rig."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.migrate.compare import (
    AppEvent,
    AppEventKind,
    Frame,
    Recording,
    Stats,
    by_identifier,
    compare,
    frames,
    latencies,
    percentile,
)
from gatewaylab.migrate.compare_report import (
    blocks,
    markdown,
    read_recording,
    to_html,
    write_recording,
    write_report,
)

SDO_REQ = bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])
SDO_ANS = bytes([0x43, 0x00, 0x10, 0, 0x92, 0x01, 0x02, 0x00])
BASE = [(0.001, 0x602, SDO_REQ), (0.0013, 0x582, SDO_ANS), (0.002, 0x080, b""), (0.0022, 0x182, b"\x37\x12")]


def rec(name: str, items: list[tuple[float, int, bytes]]) -> Recording:
    return Recording(name, frames(items))


def test_identical_traces_are_identical_whatever_the_timing() -> None:
    """Issue 13 part 3: 'Exit status non-zero when the CAN traffic differs'; timing differences alone
    are not a traffic difference: the same frames later in time compare identical."""
    a = rec("esd", BASE)
    b = rec("ecan", [(t * 2 + 0.0005, i, d) for t, i, d in BASE])
    c = compare(a, b)
    assert c.identical
    assert (c.only, c.moved, c.payload) == ((), (), ())
    assert c.verdict().startswith("identical CAN traffic: 4 frames")


def test_frame_only_in_one_trace() -> None:
    """Issue 13 part 3 'frames only in one trace': an extra frame in the second trace is found, with
    its index there, and nothing else is reported."""
    extra = (0.0015, 0x123, b"\x01")
    c = compare(rec("esd", BASE), rec("ecan", [*BASE[:2], extra, *BASE[2:]]))
    assert not c.identical
    assert [(o.side, o.index, o.frame.can_id) for o in c.only] == [(1, 2, 0x123)]
    assert (c.moved, c.payload) == ((), ())
    assert c.only_in(0) == ()
    assert "1 only through ecan" in c.verdict()


def test_order_difference() -> None:
    """Issue 13 part 3 'order differences': the same frames, two of them swapped, are one frame in
    another order, not two frames only in one trace."""
    swapped = [BASE[0], BASE[1], BASE[3], BASE[2]]
    c = compare(rec("esd", BASE), rec("ecan", swapped))
    assert c.only == ()
    assert c.payload == ()
    assert len(c.moved) == 1
    assert c.moved[0].frame.can_id in (0x080, 0x182)


def test_payload_difference() -> None:
    """Issue 13 part 3 'payload differences': the same identifier at the same place with other data
    is a payload difference (both frames named), aligned per (id, payload) sequence."""
    other = list(BASE)
    other[3] = (0.0022, 0x182, b"\x37\x16")
    c = compare(rec("esd", BASE), rec("ecan", other))
    assert c.only == () and c.moved == ()
    assert [(p.index_a, p.index_b, p.a.data, p.b.data) for p in c.payload] == [(3, 3, b"\x37\x12", b"\x37\x16")]
    summary = by_identifier(c)
    assert [(s.can_id, s.payload) for s in summary] == [(0x182, 1)]


def test_all_kinds_at_once_and_by_identifier() -> None:
    """Issue 13 part 3: a missing frame, an extra one and a changed payload in one pair of traces are
    each reported once; the summary by identifier says who sent them."""
    a = [(0.0, 0x100, b"\x01"), (0.1, 0x200, b"\x02"), (0.2, 0x300, b"\x03"), (0.3, 0x400, b"\x04")]
    b = [(0.0, 0x100, b"\x01"), (0.1, 0x200, b"\x09"), (0.3, 0x400, b"\x04"), (0.4, 0x500, b"\x05")]
    app_a = (AppEvent(AppEventKind.SEND, Frame(0.0, 0x100, b"\x01")),)
    c = compare(Recording("esd", frames(a), app_a), Recording("ecan", frames(b)))
    assert [(o.side, o.frame.can_id) for o in c.only] == [(0, 0x300), (1, 0x500)]
    assert [(p.a.can_id, p.b.data) for p in c.payload] == [(0x200, b"\x09")]
    rows = {s.can_id: (s.only_a, s.only_b, s.payload, s.sender) for s in by_identifier(c)}
    assert rows == {0x200: (0, 0, 1, "other nodes"), 0x300: (1, 0, 0, "other nodes"),
                    0x500: (0, 1, 0, "other nodes")}


def test_latencies_match_sends_and_receptions_to_bus_frames() -> None:
    """Issue 13 part 3 'latency distributions (master -> CAN and CAN -> master)': send() at 0.5 ms,
    the request ends on the bus at 1.0 ms (0.5 ms); the answer ends at 1.3 ms and is handed to
    recv() at 2.0 ms (0.7 ms). Bus frames nobody sent or received count in neither."""
    app = (AppEvent(AppEventKind.SEND, Frame(0.0005, 0x602, SDO_REQ)),
           AppEvent(AppEventKind.RECV, Frame(0.002, 0x582, SDO_ANS)),
           AppEvent(AppEventKind.SEND, Frame(0.0019, 0x080, b"")))
    lat = latencies(Recording("esd", frames(BASE), app))
    assert [round(v, 9) for v in lat.to_can] == [0.0005, 0.0001]
    assert [round(v, 9) for v in lat.to_master] == [0.0007]
    assert lat.sent_by_app == frozenset({0, 2})
    assert (lat.unmatched_sends, lat.unmatched_recvs) == (0, 0)


def test_a_send_never_on_the_bus_is_unmatched() -> None:
    """Issue 13 part 3: a frame the application sent that never reached the bus has no latency; it
    is counted (and the bus trace shows it missing)."""
    app = (AppEvent(AppEventKind.SEND, Frame(0.0, 0x7FF, b"\xff")),)
    lat = latencies(Recording("esd", frames(BASE), app))
    assert lat.to_can == () and lat.unmatched_sends == 1


def test_nearest_rank_percentiles() -> None:
    """Issue 13 part 3 'latency distributions': p50 / p99 / max are nearest-rank values of the
    measured latencies (no interpolation: every number in the report was measured)."""
    values = [i / 1000 for i in range(1, 101)]        # 1 .. 100 ms
    assert percentile(values, 50) == 0.050
    assert percentile(values, 99) == 0.099
    s = Stats.of(values)
    assert s is not None and (s.count, s.max) == (100, 0.1)
    assert Stats.of([]) is None


keys = st.tuples(st.sampled_from([0x080, 0x182, 0x202, 0x582, 0x602]), st.binary(max_size=2))


@settings(max_examples=150, deadline=None)
@given(st.lists(keys, max_size=25), st.lists(keys, max_size=25))
def test_every_frame_is_matched_or_reported_once(a_keys: list[tuple[int, bytes]],
                                                 b_keys: list[tuple[int, bytes]]) -> None:
    """Issue 13 part 3 (property): whatever the two traces, every frame of each is either aligned
    with one of the other, or reported exactly once (only in one, another order, other payload);
    a trace compared with itself is identical."""
    a = rec("a", [(k * 0.001, i, d) for k, (i, d) in enumerate(a_keys)])
    b = rec("b", [(k * 0.001, i, d) for k, (i, d) in enumerate(b_keys)])
    c = compare(a, b)
    reported_a = [o.index for o in c.only_in(0)] + [m.index_a for m in c.moved] + [p.index_a for p in c.payload]
    reported_b = [o.index for o in c.only_in(1)] + [m.index_b for m in c.moved] + [p.index_b for p in c.payload]
    assert len(reported_a) == len(set(reported_a)) and len(reported_b) == len(set(reported_b))
    assert len(a.bus) - len(reported_a) == len(b.bus) - len(reported_b)     # the aligned rest, pairwise
    assert c.identical == (a_keys == b_keys)
    assert compare(a, a).identical


def test_traces_round_trip_through_python_can_csv(tmp_path: Path) -> None:
    """Issue 13 part 3 'records both buses with python-can writers': the bus frames and the
    application's events written with can.CSVWriter read back as the same recording."""
    app = (AppEvent(AppEventKind.SEND, Frame(0.0005, 0x602, SDO_REQ)),
           AppEvent(AppEventKind.RECV, Frame(0.002, 0x582, SDO_ANS)))
    original = Recording("esd CAN-EtherCAT", (*frames(BASE), Frame(0.003, 0x1ABCDEF, b"\x01", True)), app, 0.01)
    names = [p.name for p in write_recording(tmp_path, "esd", original)]
    assert names == ["esd.bus.csv", "esd.sent.csv", "esd.received.csv"]
    assert read_recording(tmp_path, "esd", "esd CAN-EtherCAT", 0.01) == original


def test_report_names_the_differences(tmp_path: Path) -> None:
    """Issue 13 part 3: 'a Markdown/HTML report with plots (latency histograms, a frame timeline) and a
    one-line verdict'; the report lists the frame only in one trace and the payload difference."""
    other = list(BASE)
    other[3] = (0.0022, 0x182, b"\x37\x16")
    other.append((0.004, 0x123, b"\xaa"))
    c = compare(rec("esd CAN-EtherCAT", BASE), rec("ECAN-Lite MCAN0", other))
    md = write_report(tmp_path, c, "compare test", [("rig", "r.toml")], ["esd.bus.csv"])
    text = md.read_text()
    assert "**different**" in text
    assert "Frames only through ECAN-Lite MCAN0 (1):" in text and "123 [1] AA" in text
    assert "182 [2] 37 12" in text and "182 [2] 37 16" in text
    html = (tmp_path / "report.html").read_text()
    assert "<table>" in html and "123 [1] AA" in html and 'src="timeline.png"' in html
    for png in ("latency.png", "timeline.png"):
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    again = markdown(blocks(c, "compare test", [("rig", "r.toml")], ["esd.bus.csv"]))
    assert again == text
    assert to_html(blocks(c, "a <b>", [], []), "a <b>").count("a &lt;b&gt;") == 2
