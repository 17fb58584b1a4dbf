"""Arbitration and delivery timing per ISO 11898-1 (issue 2, section 3)."""

import pytest

from gatewaylab.bus import CanFrame, ErrorState, Outcome, VirtualBus, frame_duration
from gatewaylab.bus.bus import ZERO_TIME_BURST
from gatewaylab.bus.timing import error_duration


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


def test_arbitration_step_names_the_winner_and_the_outcome_without_changing_anything(clock, bus, attach) -> None:
    """The arbitration step (issue 9 'a pure arbitration step that returns a transmission record with an Outcome'):
    lowest arbitration field wins (CAN 2.0 part A §2 'Arbitration'); without another node the outcome is an ACK
    error (CAN 2.0 §7 'ACK error'); asking twice gives the same answer."""
    a, _ = attach("a")
    b, _ = attach("b")
    a.send(CanFrame(0x200, b"\x01"))
    b.send(CanFrame(0x100, b"\x02"))
    step = bus.next_transmission(clock.now())
    assert step == bus.next_transmission(clock.now())
    assert step is not None and step.sender is b and step.frame.can_id == 0x100 and step.outcome is Outcome.SENT
    assert step.end - step.start == pytest.approx(frame_duration(step.frame, 1_000_000, 5_000_000))
    clock.advance(0.01)
    assert bus.stats.frames == 2
    bus.detach(b)
    a.send(CanFrame(0x300))
    lone = bus.next_transmission(clock.now())
    assert lone is not None and lone.outcome is Outcome.ACK_ERROR


def test_without_timing_frames_end_at_once_in_bounded_bursts(clock, attach) -> None:
    """docs/bus.md: `timing=False` gives every frame zero duration, arbitration order still applies; at most
    ZERO_TIME_BURST frames end in one clock event, so the clock's owner keeps control between bursts (issue 15)."""
    untimed = VirtualBus(clock, "fast", 1_000_000, timing=False)
    got: list[int] = []
    tx = untimed.attach("tx")
    untimed.attach("rx", on_frame=lambda f, t: got.append(f.can_id))
    other = untimed.attach("other")
    queued = [0x300 + i for i in range(2 * ZERO_TIME_BURST + 5)]
    for can_id in queued:
        tx.send(CanFrame(can_id))
    other.send(CanFrame(0x050))
    clock.step()                # one arbitration event: 0x050 wins (0x300 heads tx's FIFO queue)
    assert got == [0x050, *queued[:ZERO_TIME_BURST - 1]] and clock.now() == 0.0
    clock.step()
    assert len(got) == 2 * ZERO_TIME_BURST
    clock.run_while(untimed.is_busy)
    assert got == [0x050, *queued] and clock.now() == 0.0


def test_lone_sender_without_timing_does_not_stop_the_clock(clock) -> None:
    """A lone sender retransmits for ever (CAN 2.0 §8 rule 3 exception 1, docs/bus.md 'Errors'); on a bus without
    frame timing its error frames still take their time (docs/decisions.md), so simulated time moves on."""
    untimed = VirtualBus(clock, "fast", 1_000_000, timing=False)
    lone = untimed.attach("lone")
    lone.send(CanFrame(0x100, b"\x01"))
    clock.advance(0.01)
    assert clock.now() == 0.01 and lone.state is ErrorState.ERROR_PASSIVE and lone.tx_queue
    assert 0 < untimed.stats.error_frames < 0.01 / error_duration(CanFrame(0x100, b"\x01"), False, 1_000_000) + 1
