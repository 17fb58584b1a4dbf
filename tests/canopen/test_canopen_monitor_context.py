"""The decoder in context (issue 25): an identifier is CANopen only when the frame fits it and the node is
known; error frames and controller states, nodes that go silent, known nodes listed before they speak,
hex at the value's own width, the mode column after a write of 0x6060."""

from __future__ import annotations

import struct

from gatewaylab.bus import CanFrame
from gatewaylab.bus.errorframe import bus_error, state_change
from gatewaylab.canopen.monitor import BusMonitor, hex_at_width
from gatewaylab.devices.canopen_drive.objects import build_object_dictionary


def test_a_plain_0x100_frame_is_shown_raw_not_as_a_time_stamp() -> None:
    """CiA 301 7.2.6 TIME: the TIME_OF_DAY object is 6 bytes; a 4-byte 0x100 frame is something else:
    shown as candump prints it, with its data."""
    m = BusMonitor()
    (ev,) = m.feed(CanFrame(0x100, bytes.fromhex("DEADBEEF")), 1.0)
    assert (ev.kind, ev.text) == ("frame", "100   [4]  DE AD BE EF")
    (ev,) = m.feed(CanFrame(0x100, struct.pack("<IH", 1000, 1)), 1.0)
    assert (ev.kind, ev.text) == ("time", "TIME 1984-01-02T00:00:01.000+00:00")


def test_pdo_and_emcy_ids_of_an_unknown_node_are_raw_frames() -> None:
    """CiA 301 7.3.5 predefined connection set: 0x185 is TPDO1 and 0x85 the EMCY of node 5 only if there is
    a node 5; before anything says so they are shown raw, after its boot-up as node 5's."""
    m = BusMonitor()
    assert m.feed(CanFrame(0x185, b"\x01\x02"), 0.0)[0].text == "185   [2]  01 02"
    assert m.feed(CanFrame(0x85, bytes(8)), 0.0)[0].kind == "frame"
    assert m.feed(CanFrame(0x705, b"\x00"), 0.1)[0].kind == "boot-up"
    assert "TPDO1 from node 5" in m.feed(CanFrame(0x185, b"\x01\x02"), 0.2)[0].text
    assert m.feed(CanFrame(0x85, bytes.fromhex("1023010000000000")), 0.3)[0].kind == "emcy"
    # wrong shapes stay raw: a 2-byte "SDO", a 3-byte "heartbeat", a 7-byte LSS frame
    assert [m.feed(f, 0.4)[0].kind for f in (CanFrame(0x605, b"\x40\x00"), CanFrame(0x705, b"\x05\x00\x00"),
                                             CanFrame(0x7E5, bytes(7)))] == ["frame"] * 3


def test_known_nodes_are_listed_before_they_speak() -> None:
    """The rig's ready file lists its nodes: the node table shows them at once (NMT '?')."""
    m = BusMonitor(known=[2, 3])
    assert sorted(m.nodes) == [2, 3] and m.nodes[2].nmt == "?"


def test_error_frames_and_state_changes_are_bus_events() -> None:
    """ISO 11898-1 fault confinement as SocketCAN reports it: an error frame with its type, the
    controller's state changes (error-passive, bus-off, restarted)."""
    m = BusMonitor()
    (ev,) = m.feed_error(bus_error("crc", False, 0, 1), 1.0)
    assert ev.kind == "bus" and ev.text == "error frame: crc-error, TEC 0 REC 1"
    (ev,) = m.feed_error(bus_error("stuff", True, 8, 0), 1.0)
    assert ev.text == "error frame: bit-stuffing-error (as transmitter), TEC 8 REC 0"
    m.feed_error(state_change("error-active", "error-passive", 0, 128), 1.1)
    assert m.bus_state == "error-passive"
    (ev,) = m.feed_error(state_change("error-passive", "bus-off", 256, 0), 1.2)
    assert m.bus_state == "bus-off" and ev.text.startswith("controller bus-off")
    m.feed_error(state_change("bus-off", "error-active", 0, 0), 1.3)
    assert m.bus_state == "error-active" and m.error_frames == 5


def test_a_node_whose_heartbeat_stops_left_the_bus_and_comes_back() -> None:
    """CiA 301 7.2.8.3.2.2 heartbeat consumer: a node silent for longer than its period (three periods
    here, at least 0.5 s) is gone: one 'node' event; its next heartbeat says it is back."""
    m = BusMonitor()
    for k in range(5):
        m.feed(CanFrame(0x702, b"\x05"), 0.1 * k)
    assert m.tick(0.7) == []
    (ev,) = m.tick(1.0)
    assert ev.kind == "node" and ev.node == 2 and ev.text.startswith("node 2 left the bus: no heartbeat for 0.60 s")
    assert m.nodes[2].nmt == "silent" and m.tick(2.0) == []
    (ev,) = m.feed(CanFrame(0x702, b"\x05"), 3.0)
    assert ev.text == "node 2 is back: heartbeat of node 2: Operational" and m.nodes[2].nmt == "Operational"


def test_hex_is_at_the_values_own_width() -> None:
    """A negative INTEGER32 is 0xFFFF15A0 (its 32 bits), not a 64-bit pattern; a UNSIGNED16 0x0240."""
    assert hex_at_width(-60000, 4) == "0xFFFF15A0"
    assert hex_at_width(576, 2) == "0x0240"
    assert hex_at_width(-1, None) == "0xFF"
    m = BusMonitor({2: build_object_dictionary(0, 2)})
    (ev,) = m.feed(CanFrame(0x182, struct.pack("<Hi", 0x0637, -60000)), 1.0)
    assert ev.text == "TPDO1 node 2: Statusword=1591 (0x0637), Position actual value=-60000 (0xFFFF15A0)"
    assert m.nodes[2].position == -60000


def test_the_mode_column_fills_after_a_write_of_0x6060() -> None:
    """CiA 402 6.2.1 modes of operation (0x6060): written by SDO, the table shows the mode asked for
    until the display (0x6061) says otherwise."""
    m = BusMonitor({2: build_object_dictionary(0, 2)})
    m.feed(CanFrame(0x602, bytes.fromhex("2F60600008000000")), 1.0)
    m.feed(CanFrame(0x582, bytes.fromhex("6060600000000000")), 1.001)
    assert m.nodes[2].mode_name == "CYCLIC_SYNC_POSITION"
