"""The decoded monitor's time order, sans-I/O (cli/monitor_order.py, the CanWatcher of cli/monitor.py;
docs/monitor.md "Time order"): events of the frames and of the rig's controller polls given out sorted
by time, and a controller that came back dated before the first frame its node sent (CiA 301: a node
off the bus sends nothing; its boot-up follows its return)."""

from __future__ import annotations

from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.monitor import MonitorEvent
from gatewaylab.cli.monitor import CanWatcher
from gatewaylab.cli.monitor_order import TimeOrder, sender_node


def _ev(t: float, text: str = "") -> MonitorEvent:
    return MonitorEvent(t, "frame", text or f"{t}")


def test_events_come_out_sorted_once_held_long_enough() -> None:
    """A controller event stamped 4.2046 read before a heartbeat of 4.2036 (the issue's example) comes
    out after it; nothing younger than the horizon comes out before the end."""
    order = TimeOrder(0.5)
    order.add([_ev(4.2046, "unplug")])
    order.add([_ev(4.2036, "heartbeat"), _ev(4.5, "later")])
    assert order.due(4.6) == []
    assert [e.text for e in order.due(4.71)] == ["heartbeat", "unplug"]
    assert [e.text for e in order.flush()] == ["later"]
    assert len(order) == 0


@given(st.lists(st.lists(st.floats(0, 100, allow_nan=False), max_size=5), max_size=30))
def test_whatever_comes_in_goes_out_once_and_sorted(batches: list[list[float]]) -> None:
    """Every event added comes out exactly once; each ``due`` batch and the final flush are sorted, and
    events of equal time keep the order they came in."""
    order = TimeOrder(1.0)
    out: list[MonitorEvent] = []
    added: list[MonitorEvent] = []
    for k, batch in enumerate(batches):
        events = [MonitorEvent(t, "frame", f"{k}.{i}") for i, t in enumerate(batch)]
        added += events
        order.add(events)
        got = order.due(float(k))
        assert [e.t for e in got] == sorted(e.t for e in got)
        out += got
    rest = order.flush()
    assert [e.t for e in rest] == sorted(e.t for e in rest)
    out += rest
    assert sorted(e.text for e in out) == sorted(e.text for e in added)
    for t in {e.t for e in out}:
        assert [e.text for e in out if e.t == t] == [e.text for e in added if e.t == t]


def test_sender_node_is_the_predefined_connection_set() -> None:
    """CiA 301 7.3.5: EMCY 0x80+n, TPDOs 0x180/0x280/0x380/0x480+n, SDO response 0x580+n, heartbeat
    0x700+n are the node's own; NMT, SYNC, TIME, RPDOs, SDO requests are not."""
    assert [sender_node(CanFrame(cid, b"\0")) for cid in (0x702, 0x183, 0x4FF, 0x585, 0x081)] == [2, 3, 127, 5, 1]
    assert [sender_node(CanFrame(cid, b"\0")) for cid in (0x000, 0x080, 0x100, 0x202, 0x602, 0x7E4)] == [None] * 6
    assert sender_node(CanFrame(0x702, b"\0", extended=True)) is None


def _answer(**states: dict[str, Any]) -> dict[str, Any]:
    return {"buses": {"can0": states}}


UP = {"state": "error-active", "tec": 0, "rec": 0, "connected": True, "bus_offs": 0}
DOWN = {**UP, "connected": False}


def test_a_controller_that_came_back_is_dated_before_its_boot_up() -> None:
    """docs/faults.md power-cycle: the drive leaves the bus, then boots. The poll that sees it back (at 14.524)
    comes after its boot-up (14.121): the event is dated just before the boot-up, not at the poll."""
    w = CanWatcher("unix:/nonexistent", "can0", nodes={"axis2": 2})
    assert w.changes(_answer(axis2=UP), 13.5) == []
    (gone,) = w.changes(_answer(axis2=DOWN), 14.0)
    assert gone.text == "CAN axis2: unplugged, left the bus" and gone.t == 14.0
    w.saw(CanFrame(0x703, b"\x05"), 14.05)            # another node: no bearing on axis2
    w.saw(CanFrame(0x702, b"\x00"), 14.121)           # boot-up of node 2
    assert w.changes(_answer(axis2=UP), 14.524) == []   # held: its date may still move
    (back,) = w.release(14.524)
    assert back.text == "CAN axis2: plugged in again" and 14.12 < back.t < 14.121


def test_a_frame_read_after_the_poll_still_dates_the_event() -> None:
    """A boot-up stamped before the poll but read after its answer (it was on its way): the held event
    is dated by it, and given out once a frame at least as new as the poll has been read."""
    w = CanWatcher("unix:/nonexistent", "can0", nodes={"axis2": 2})
    w.changes(_answer(axis2=DOWN), 14.0)
    assert w.changes(_answer(axis2=UP), 14.524) == []
    assert w.release(14.53) == []                      # frames before 14.524 may still come
    w.saw(CanFrame(0x702, b"\x00"), 14.523)
    w.saw(CanFrame(0x182, b"\x00\x00"), 14.6)
    (back,) = w.release(14.61)
    assert 14.522 < back.t < 14.523


def test_an_unknown_controller_keeps_the_poll_time() -> None:
    """A controller the ready file does not list as a CANopen node (no node-ID to date it by): its
    events keep the time of the poll that saw them."""
    w = CanWatcher("unix:/nonexistent", "can0")
    w.changes(_answer(gw=DOWN), 1.0)
    (back,) = w.changes(_answer(gw=UP), 2.0)
    assert back.t == 2.0 and back.text == "CAN gw: plugged in again"


def test_the_first_answer_only_says_how_things_are() -> None:
    """The first answer tells states, not changes: an error-passive controller at the monitor's start
    keeps the time of that answer; one that joins later is a controller that came back."""
    w = CanWatcher("unix:/nonexistent", "can0", nodes={"axis2": 2, "axis3": 3})
    w.saw(CanFrame(0x702, b"\x00"), 0.5)
    (passive,) = w.changes(_answer(axis2={**UP, "state": "error-passive", "tec": 128}), 1.0)
    assert passive.t == 1.0 and "error-passive" in passive.text
    w.saw(CanFrame(0x703, b"\x00"), 1.2)
    assert w.changes(_answer(axis2={**UP, "state": "error-passive", "tec": 128}, axis3=UP), 1.5) == []
    (joined,) = w.release(1.5)
    assert joined.text == "CAN axis3: joined the bus" and 1.19 < joined.t < 1.2
