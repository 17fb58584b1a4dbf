"""Fault-injection primitives of the bus (issue 14 'Break'; docs/bus.md 'Fault injection'), checked
against the fault-confinement rules of CAN 2.0 §8 as carried into ISO 11898-1."""

import pytest

from gatewaylab.bus import CanFrame, ErrorFrameEvent, ErrorKind, ErrorState, StateChangeEvent, TxAbortedEvent
from gatewaylab.common.errors import LocalError


def test_drop_next_of_one_id_spares_the_others(clock, bus, attach) -> None:
    """docs/bus.md: `drop_next(n, can_id)` drops the next n frames of that id only; the sender
    sees success (TxDone), nobody receives them, other ids pass."""
    a, _ = attach("a")
    _, rx = attach("rx")
    bus.drop_next(2, can_id=0x181)
    for i in range(3):
        a.send(CanFrame(0x181, bytes([i])))
        a.send(CanFrame(0x281, bytes([i])))
    clock.advance(0.01)
    assert rx.ids == [0x281, 0x281, 0x181, 0x281]
    assert [f.data for f, _ in rx.frames if f.can_id == 0x181] == [b"\x02"]
    assert bus.stats.dropped_frames == 2 and a.tec == 0
    assert bus.fault_plan is None      # spent: the hot path is back to one test


def test_corrupt_next_of_one_id_is_a_crc_error_and_retransmitted(clock, bus, attach) -> None:
    """ISO 11898-1 / CAN 2.0 §8 rules 1 and 3: a corrupted frame is an error frame, the transmitter's
    TEC + 8, each receiver's REC + 1; the frame is retransmitted (a retransmission is the next frame
    of that id, so corrupt_next(2, id) destroys the frame twice)."""
    a, arec = attach("a")
    b, rx = attach("b")
    bus.corrupt_next(2, can_id=0x701)
    a.send(CanFrame(0x100))
    a.send(CanFrame(0x701, b"\x05"))
    clock.advance(0.01)
    assert rx.ids == [0x100, 0x701]
    assert a.stats.tx_retransmissions == 2 and bus.stats.error_frames == 2
    crc = [e for e in arec.events if isinstance(e, ErrorFrameEvent)]
    assert [e.kind for e in crc] == [ErrorKind.CRC, ErrorKind.CRC]
    assert all(e.frame is not None and e.frame.can_id == 0x701 for e in crc)
    assert a.tec == 16 - 1 and b.rec == 2 - 1


def test_error_frames_for_a_time_drive_a_sender_bus_off_and_then_stop(clock, bus, attach) -> None:
    """CAN 2.0 §8 rules 3 and 10: every frame destroyed, the transmitter's TEC climbs by 8 per attempt;
    above 255 it is bus-off (its queue aborted). After the span frames pass again."""
    a, arec = attach("a")
    _, rx = attach("rx")
    bus.error_frames(0.05)
    a.send(CanFrame(0x123))
    clock.advance(0.01)
    states = [e.new for e in arec.events if isinstance(e, StateChangeEvent)]
    assert states == [ErrorState.ERROR_PASSIVE, ErrorState.BUS_OFF, ErrorState.ERROR_ACTIVE]  # rule 12
    assert sum(isinstance(e, ErrorFrameEvent) for e in arec.events) == 32     # 32 x 8 = 256
    assert any(isinstance(e, TxAbortedEvent) for e in arec.events)
    assert rx.frames == []
    clock.advance(0.1)           # after the span
    a.send(CanFrame(0x124))
    clock.advance(0.01)
    assert rx.ids == [0x124]


def test_error_frames_every_nth_frame_leave_a_working_bus(clock, bus, attach) -> None:
    """One frame in ten destroyed: TEC + 8 per error, - 1 per success (CAN 2.0 §8 rules 3 and 7), so
    the sender stays error-active and every frame arrives once."""
    a, _ = attach("a")
    _, rx = attach("rx")
    bus.error_frames(1.0, every=10)
    for i in range(50):
        a.send(CanFrame(0x200, bytes([i])))
    clock.advance(0.05)
    assert [f.data[0] for f, _ in rx.frames] == list(range(50))
    assert a.stats.tx_retransmissions == 6     # frames 0, 10, ... of 56 attempts
    assert a.state is ErrorState.ERROR_ACTIVE


def test_force_error_passive_then_one_success_is_active_again(clock, bus, attach) -> None:
    """CAN 2.0 §8 rules 9, 7 and 11: TEC 128 is error-passive; a successful transmission takes
    one off and at 127 the node is error-active again."""
    a, arec = attach("a")
    attach("rx")
    bus.force_error_passive(a)
    assert a.state is ErrorState.ERROR_PASSIVE and a.tec == 128
    a.send(CanFrame(0x100))
    clock.advance(0.01)
    assert a.state is ErrorState.ERROR_ACTIVE and a.tec == 127
    assert [e.new for e in arec.events if isinstance(e, StateChangeEvent)] == [
        ErrorState.ERROR_PASSIVE, ErrorState.ERROR_ACTIVE]


def test_stuck_dominant_sends_transmitters_bus_off_and_recovers_after(clock, bus, attach) -> None:
    """CAN 2.0 §8 rule 6: on a bus held dominant every transmitter counts TEC + 8 per 8 dominant bits
    and goes bus-off (rule 10), every receiver REC + 8 and goes error-passive; no frame completes.
    Released, the bus is idle: bus-off recovers after 128 x 11 recessive bits (rule 12), a receiver's
    REC drops to 119..127 with its next good frame (rule 8), queued frames go out."""
    a, arec = attach("a")
    b, brx = attach("b")
    a.send(CanFrame(0x181, b"\x01"))
    clock.advance(0.00003)              # the frame is on the wire
    bus.stuck_dominant(0.2)
    assert bus.stuck and bus.is_busy()
    clock.advance(0.01)
    assert a.state is ErrorState.BUS_OFF and not a.tx_queue
    assert b.state is ErrorState.ERROR_PASSIVE
    assert brx.frames == []
    b.send(CanFrame(0x701, b"\x05"))    # a node that wants to send during the jam is a transmitter
    clock.advance(0.01)
    assert b.state is ErrorState.BUS_OFF
    kinds = {e.kind for e in arec.events if isinstance(e, ErrorFrameEvent)}
    assert kinds == {ErrorKind.BIT}
    clock.advance(0.1)                  # still held: no recovery without recessive bits
    assert a.state is ErrorState.BUS_OFF
    clock.advance(0.08 + 128 * 11 / 1_000_000 + 1e-4)
    assert not bus.stuck
    assert a.state is ErrorState.ERROR_ACTIVE and b.state is ErrorState.ERROR_ACTIVE
    a.send(CanFrame(0x182, b"\x02"))
    clock.advance(0.01)
    assert brx.ids == [0x182]


def test_stuck_dominant_receivers_only_count_rec(clock, bus, attach) -> None:
    """An idle bus held dominant: nobody transmits, so only REC moves (rules 1 and 6) and nobody goes
    bus-off; a node whose frame waits for the release sends it then. ISO 11898-1 bus monitoring
    mode: a listen-only node detects the error but sends no flag and changes no counter."""
    a, _ = attach("a")
    b, brx = attach("b")
    spy, spy_rec = attach("spy", listen_only=True)
    bus.stuck_dominant(0.05)
    clock.advance(0.01)
    assert a.tec == 0 and a.state is ErrorState.ERROR_PASSIVE and a.rec > 127
    # a listen-only controller sees the error but never counts (docs/bus.md)
    assert [e.kind for e in spy_rec.events if isinstance(e, ErrorFrameEvent)] == [ErrorKind.STUFF]
    assert spy.rec == 0 and spy.state is ErrorState.ERROR_ACTIVE
    clock.advance(0.05)
    a.send(CanFrame(0x100))
    clock.advance(0.01)
    assert brx.ids == [0x100] and b.rec == 120      # rule 8: from above 127 to 119..127


def test_fault_arguments_are_checked(bus, attach) -> None:
    """Impossible faults are refused with LocalError (a fault plan never goes negative)."""
    a, _ = attach("a")
    with pytest.raises(LocalError):
        bus.drop_next(0)
    with pytest.raises(LocalError):
        bus.error_frames(0)
    with pytest.raises(LocalError):
        bus.stuck_dominant(-1)
    bus.force_bus_off(a)
    with pytest.raises(LocalError):
        bus.force_error_passive(a)
