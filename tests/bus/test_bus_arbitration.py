"""Arbitration and delivery timing per ISO 11898-1 (issue 2, section 3)."""

import pytest

from gatewaylab.bus import CanFrame, frame_duration


def test_pending_frames_go_out_lowest_identifier_first(clock, bus, attach) -> None:
    """Bitwise arbitration: of frames pending at the same instant the lowest identifier wins (CAN 2.0 part A §2
    'Arbitration'; docs/bus.md 'Arbitration')."""
    a, _ = attach("a")
    b, _ = attach("b")
    c, _ = attach("c")
    _, rx = attach("rx")
    a.send(CanFrame(0x300, b"\x03"))
    b.send(CanFrame(0x100, b"\x01"))
    c.send(CanFrame(0x200, b"\x02"))
    clock.advance(0.01)
    assert rx.ids == [0x100, 0x200, 0x300]


def test_frame_is_received_at_the_instant_it_ends(clock, bus, attach) -> None:
    """Receivers get a frame when it ends, at start + its duration from the bit-count model (docs/bus.md 'Timing';
    issue 2 §3)."""
    a, _ = attach("a")
    _, rx = attach("rx")
    clock.advance(0.5)
    frame = CanFrame(0x123, bytes(8))
    a.send(frame)
    a.send(CanFrame(0x124, bytes(8)))
    clock.advance(0.01)
    d = frame_duration(frame, 1_000_000)
    assert [t for _, t in rx.frames] == pytest.approx([0.5 + d, 0.5 + 2 * d])


def test_base_frame_beats_extended_frame_with_same_base_id(clock, bus, attach) -> None:
    """An 11-bit frame beats a 29-bit frame with the same base id: its IDE bit is dominant where the extended frame
    sends SRR/IDE recessive (CAN 2.0B §3.1, issue 2 §3)."""
    a, _ = attach("a")
    b, _ = attach("b")
    _, rx = attach("rx")
    a.send(CanFrame(0x123 << 18, b"x", extended=True))
    b.send(CanFrame(0x123, b"y"))
    clock.advance(0.01)
    assert [(f.can_id, f.extended) for f, _ in rx.frames] == [(0x123, False), (0x123 << 18, True)]


def test_data_frame_beats_remote_frame_with_same_id(clock, bus, attach) -> None:
    """A data frame beats a remote frame with the same id: dominant RTR bit (CAN 2.0 §3.1 'Arbitration field',
    issue 2 §3)."""
    a, _ = attach("a")
    b, _ = attach("b")
    _, rx = attach("rx")
    a.send(CanFrame(0x181, rtr=True, dlc=8))
    b.send(CanFrame(0x181, bytes(8)))
    clock.advance(0.01)
    assert [f.rtr for f, _ in rx.frames] == [False, True]


def test_each_controller_sends_its_own_queue_in_fifo_order(clock, bus, attach) -> None:
    """Each controller's queue is FIFO; only its head competes (docs/bus.md 'Arbitration', docs/decisions.md)."""
    a, _ = attach("a")
    _, rx = attach("rx")
    for can_id in (0x500, 0x100, 0x300):
        a.send(CanFrame(can_id))
    clock.advance(0.01)
    assert rx.ids == [0x500, 0x100, 0x300]


def test_a_frame_queued_while_the_bus_is_busy_waits_for_the_end(clock, bus, attach) -> None:
    """A frame never interrupts one on the wire: arbitration happens only when the bus is idle (CAN 2.0 part A §2 'Bus
    access')."""
    a, _ = attach("a")
    b, _ = attach("b")
    _, rx = attach("rx")
    a.send(CanFrame(0x700, bytes(8)))
    clock.advance(10e-6)          # 0x700 is on the wire now
    b.send(CanFrame(0x001, bytes(8)))
    clock.advance(0.01)
    assert rx.ids == [0x700, 0x001]


def test_fd_frame_uses_both_bit_rates_and_sender_does_not_receive_its_own(clock, bus, attach) -> None:
    """CAN FD with BRS: data phase at the data bit rate (docs/bus.md 'Timing'); a controller does not receive its
    own frames unless asked (python-can receive_own_messages semantics)."""
    a, arx = attach("a")
    _, rx = attach("rx")
    frame = CanFrame(0x10, bytes(64), fd=True, brs=True)
    a.send(frame)
    clock.advance(0.01)
    assert rx.frames == [(frame, pytest.approx(frame_duration(frame, 1_000_000, 5_000_000)))]
    assert arx.frames == []


def test_receive_own_and_bus_statistics(clock, bus, attach) -> None:
    """Statistics per bus and per controller: frames, bytes, bus load % (issue 2 §3 'Statistics')."""
    a, arx = attach("a", receive_own=True)
    attach("rx")
    for _ in range(10):
        a.send(CanFrame(0x10, bytes(8)))
    clock.run_until(0.01)
    assert len(arx.frames) == 10
    assert bus.stats.frames == 10 and bus.stats.bytes == 80
    assert bus.load_percent() == pytest.approx(100 * 10 * 135e-6 / 0.01)
    assert a.stats.tx_frames == 10
