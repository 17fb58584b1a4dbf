"""The transmit queue's one way in for devices: withdraw a queued frame, send in priority order (issue 22
'one way into each lower layer': a bus ``Controller.withdraw()`` / priority-queue mode instead of touching
``tx_queue``)."""

from gatewaylab.bus import CanFrame


def test_withdraw_takes_a_queued_frame_back_but_not_the_one_on_the_wire(clock, bus, attach) -> None:
    """A frame not yet on the wire can be taken back (M_CAN TXBCR cancellation request, ECAN-Lite manual 13.6
    whitelist 0x00D4); the frame being sent completes (CAN 2.0 part A §2 'Bus access': nothing interrupts it)."""
    a, _ = attach("a")
    _, rx = attach("rx")
    first, second, third = CanFrame(0x100, bytes(8)), CanFrame(0x200, bytes(8)), CanFrame(0x300, bytes(8))
    for f in (first, second, third):
        a.send(f)
    clock.advance(10e-6)                     # first is on the wire now
    assert not a.withdraw(first)
    assert a.withdraw(third)
    assert not a.withdraw(third)             # no longer queued
    assert not a.withdraw(CanFrame(0x200, bytes(8)))   # an equal frame is not the queued object
    clock.advance(0.01)
    assert rx.ids == [0x100, 0x200]


def test_send_by_priority_orders_the_queue_by_arbitration_behind_the_frame_on_the_wire(clock, bus, attach) -> None:
    """M_CAN TX queue mode (ECAN-Lite manual 13.4, 0x800x:69 = 1: 'Queue is sorted by CAN ID arbitration
    priority'): the highest-priority queued frame leaves first, FIFO among equal identifiers, and the frame
    already on the wire keeps its place."""
    a, _ = attach("a")
    _, rx = attach("rx")
    a.send_by_priority(CanFrame(0x700, bytes(8)))
    clock.advance(10e-6)                     # 0x700 is on the wire
    for can_id, data in ((0x500, b"a"), (0x100, b"b"), (0x300, b"c"), (0x100, b"d")):
        a.send_by_priority(CanFrame(can_id, data))
    clock.advance(0.01)
    assert [(f.can_id, f.data) for f, _ in rx.frames] == [
        (0x700, bytes(8)), (0x100, b"b"), (0x100, b"d"), (0x300, b"c"), (0x500, b"a")]
