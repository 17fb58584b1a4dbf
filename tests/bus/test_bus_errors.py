"""Fault confinement (CAN 2.0 §8 'Fault Confinement') and the fault-injection API (issue 2, section 3)."""

import pytest

from gatewaylab.bus import CanFrame, ErrorFrameEvent, ErrorKind, ErrorState, StateChangeEvent, TxAbortedEvent
from gatewaylab.common.errors import LocalError


def test_lone_sender_goes_error_passive_and_stays_there(clock, bus, attach) -> None:
    """Nobody acknowledges: TEC += 8 per ACK error until 128 (error-passive); then the
    CAN 2.0 §8 rule 3 exception 1 for ACK errors of a passive transmitter keeps it there, never bus-off."""
    a, rec = attach("lone")
    a.send(CanFrame(0x100, b"\x01"))
    clock.advance(0.1)
    assert a.state is ErrorState.ERROR_PASSIVE
    assert a.tec == 128
    assert any(isinstance(e, StateChangeEvent) and e.new is ErrorState.ERROR_PASSIVE for e in rec.events)
    assert all(e.kind is ErrorKind.ACK for e in rec.events if isinstance(e, ErrorFrameEvent))
    assert a.tx_queue  # still retransmitting


def test_acknowledging_node_brings_lone_sender_back(clock, bus, attach) -> None:
    """Once another node acknowledges, the frame completes and TEC decreases by 1 per success (CAN 2.0 §8 'Fault
    Confinement' rule 7)."""
    a, _ = attach("lone")
    a.send(CanFrame(0x100, b"\x01"))
    clock.advance(0.1)
    _, rx = attach("late")
    clock.advance(0.1)
    assert len(rx.frames) == 1
    assert a.tec == 127 and a.state is ErrorState.ERROR_ACTIVE


def test_listen_only_receives_but_never_acknowledges(clock, bus, attach) -> None:
    """Listen-only controllers receive but never acknowledge or send (issue 2 §3)."""
    a, _ = attach("tx")
    lo, lrx = attach("spy", listen_only=True)
    a.send(CanFrame(0x100, b"\x01"))
    clock.advance(0.01)
    assert a.tec > 0 and not lrx.frames  # an unacknowledged frame is never completed
    with pytest.raises(LocalError):
        lo.send(CanFrame(0x1))
    _, rx = attach("rx")
    clock.advance(0.01)
    assert len(lrx.frames) == 1 and len(rx.frames) == 1


def test_forced_bus_off_recovers_after_128_times_11_recessive_bits(clock, bus, attach) -> None:
    """Bus-off recovery after 128 occurrences of 11 recessive bits (CAN 2.0 §8 'Fault Confinement'; issue 2 §3)."""
    a, rec = attach("a")
    attach("rx")
    bus.force_bus_off(a)
    assert a.state is ErrorState.BUS_OFF
    with pytest.raises(LocalError):
        a.send(CanFrame(0x1))
    clock.advance(128 * 11 / 1_000_000 - 1e-6)
    assert a.state is ErrorState.BUS_OFF
    clock.advance(2e-6)
    assert a.state is ErrorState.ERROR_ACTIVE and a.tec == 0 and a.rec == 0
    assert [e.new for e in rec.events if isinstance(e, StateChangeEvent)] == [
        ErrorState.BUS_OFF, ErrorState.ERROR_ACTIVE]


def test_corrupted_frames_are_retransmitted_and_counted(clock, bus, attach) -> None:
    """A CRC error: transmitter TEC += 8 (rule 3), receivers REC += 1 (rule 1), automatic retransmission (CAN 2.0
    §8; issue 2 §3 fault injection)."""
    a, _ = attach("a")
    b, rx = attach("b")
    bus.corrupt_next(2)
    a.send(CanFrame(0x100, b"\x01"))
    clock.advance(0.01)
    assert len(rx.frames) == 1
    assert bus.stats.error_frames == 2
    assert a.tec == 16 - 1 and b.rec == 2 - 1
    assert a.stats.tx_retransmissions == 2


def test_single_shot_controller_gives_up_after_an_error(clock, bus, attach) -> None:
    """With auto-retransmission disabled a frame is given up after its first error (issue 2 §3)."""
    a, rec = attach("a", auto_retransmit=False)
    a.send(CanFrame(0x100, b"\x01"))
    clock.advance(0.01)
    assert not a.tx_queue
    assert any(isinstance(e, TxAbortedEvent) for e in rec.events)


def test_dropped_frames_vanish_silently(clock, bus, attach) -> None:
    """Fault injection 'drop the next N frames': the sender sees success, nobody receives (issue 2 §3)."""
    a, _ = attach("a")
    _, rx = attach("rx")
    bus.drop_next(1)
    a.send(CanFrame(0x100))
    a.send(CanFrame(0x101))
    clock.advance(0.01)
    assert rx.ids == [0x101] and bus.stats.dropped_frames == 1


def test_wrong_bit_rate_sees_only_error_frames(clock, bus, attach) -> None:
    """A controller at another bit rate sees error frames and receives nothing; its own sends fail with bit errors
    until bus-off (issue 2 §3; docs/decisions.md)."""
    a, _ = attach("a")
    _, rx = attach("rx")
    slow, srx = attach("slow", bitrate=500_000)
    for i in range(130):
        a.send(CanFrame(0x100 + i))
    clock.advance(0.1)
    assert len(rx.frames) == 130 and srx.frames == []
    assert slow.stats.error_frames == 130
    assert slow.state is ErrorState.ERROR_PASSIVE
    slow.send(CanFrame(0x1))
    clock.advance(0.1)
    # Every attempt is a bit error (TEC += 8): bus-off after 32 attempts, frame flushed, then
    # automatic recovery after 128 x 11 recessive bits.
    assert [e.new for e in srx.events if isinstance(e, StateChangeEvent)] == [
        ErrorState.ERROR_PASSIVE, ErrorState.BUS_OFF, ErrorState.ERROR_ACTIVE]
    assert not slow.tx_queue and rx.ids.count(0x1) == 0


def test_disconnected_controller_neither_sends_nor_receives(clock, bus, attach) -> None:
    """Fault injection: disconnect / reconnect a controller; its queue waits (issue 2 §3)."""
    a, _ = attach("a")
    b, brx = attach("b")
    _, rx = attach("rx")
    bus.disconnect(b)
    a.send(CanFrame(0x100))
    b.send(CanFrame(0x200))
    clock.advance(0.01)
    assert brx.frames == [] and rx.ids == [0x100]
    bus.reconnect(b)
    clock.advance(0.01)
    assert rx.ids == [0x100, 0x200]


def test_synthetic_load_occupies_the_requested_share(clock, bus, attach) -> None:
    """Fault injection: synthetic bus load, measured by the bus load statistic (issue 2 §3)."""
    attach("rx")
    bus.set_load(30.0)
    clock.advance(1.0)
    assert bus.load_percent() == pytest.approx(30.0, abs=0.5)
    bus.set_load(0)
    bus.reset_stats()
    clock.advance(1.0)
    assert bus.load_percent() < 0.01  # only the tail of the frame on the wire at the reset
