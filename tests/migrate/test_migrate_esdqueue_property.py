"""Issue 13 part 2, as a property: any sequence of queue() calls (11-bit and 29-bit frames, 0..8
data bytes, RTR with a requested length) with any Tx queue size 1..16 gives the same transaction
numbers, the same frames on the bus in queue order, the same echoes back and the same batch
boundaries on the esd gateway and on the ECAN-Lite (esd manual 5.1.5.1-5.1.5.4: batches taken
whole, in order, completion a prefix; ECAN-Lite manual 10, 12)."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_migrate_esdqueue import T, echo_of, frames_of, make_side, receive_n

from gatewaylab.bus.frame import CanFrame


@st.composite
def frames(draw: Any) -> CanFrame:
    extended = draw(st.booleans())
    can_id = draw(st.integers(0, 0x1FFFFEFF if extended else 0x6FF))
    if draw(st.booleans()):
        return CanFrame(can_id, b"", extended=extended, rtr=True, dlc=draw(st.integers(0, 8)))
    return CanFrame(can_id, draw(st.binary(max_size=8)), extended=extended)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tx_queue=st.integers(1, 16), calls=st.lists(st.lists(frames(), min_size=1, max_size=12), min_size=1,
                                                    max_size=3))
def test_random_batches_identical_on_both_gateways(tx_queue: int, calls: list[list[CanFrame]]) -> None:
    outcomes = []
    for kind in ("esd", "ecanlite"):
        side = make_side(kind)
        host = side.host
        host.configure(extended=True, tx_queue=tx_queue)
        host.start(timeout=T)
        tns = [tn for batch in calls for tn in host.queue(batch)]
        sent = [f for batch in calls for f in batch]
        boundaries = set()
        deadline = host.clock.now() + T
        while not host.completed(tns[-1]):
            assert host.clock.now() < deadline
            side.cycles(1)
            done = [host.completed(t) for t in tns]
            assert done == sorted(done, reverse=True)
            boundaries.add(sum(host.accepted(t) for t in tns))
        boundaries.discard(0)       # the esd takes no batch before its first inputs were read
        assert boundaries <= {*range(tx_queue, len(sent), tx_queue), len(sent)}
        assert side.heard == sent
        echoes = frames_of(receive_n(host, len(sent)))
        assert echoes == [echo_of(f) for f in sent]
        outcomes.append((tns, side.heard, echoes, boundaries))
    assert outcomes[0] == outcomes[1]
