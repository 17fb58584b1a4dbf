"""The multi-channel frame-area budget of the ECAN-Lite manual chapter 12 (budget.py)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.common.errors import LocalError
from gatewaylab.devices.ecanlite.budget import DEFAULT_RESERVE_BYTES, MAX_PACKETS, BudgetPolicy, allocate
from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    Direction,
    Option,
    StreamLayout,
    Tsf,
    decode_stream,
    encode_stream,
    packet_size,
)


def test_policy_values() -> None:
    """Chapter 12: 0 Balanced, 1 SharedOnly, 2 Deterministic (3 reserved: no member)."""
    assert [(p.value, p.name) for p in BudgetPolicy] == [(0, "BALANCED"), (1, "SHARED_ONLY"), (2, "DETERMINISTIC")]
    with pytest.raises(ValueError):
        allocate(3, 100, [0], {0: [12]})


def test_everything_fits() -> None:
    """Chapter 12: when the frame area holds every pending packet, all go and nothing is truncated."""
    for policy in BudgetPolicy:
        alloc = allocate(policy, 1000, [0, 1, 2, 3], {0: [12, 12], 1: [68], 3: [16] * 5})
        assert dict(alloc) == {0: 2, 1: 1, 2: 0, 3: 5}
        assert alloc.left_behind == 0 and not alloc.truncated and alloc.bytes_used == 24 + 68 + 80


def test_frames_never_split_and_order_kept() -> None:
    """Chapter 12: 'A CAN_FRAME must be put into the frame area of this cycle as a whole'; a
    channel's packets leave oldest first, so one that does not fit holds back the later ones."""
    alloc = allocate(BudgetPolicy.SHARED_ONLY, 100, [0], {0: [40, 40, 30, 4]})
    assert alloc[0] == 2 and alloc.bytes_used == 80
    assert alloc.left == {0: 2} and alloc.left_behind == 2 and alloc.truncated


def test_balanced_reserves_a_minimum_per_channel() -> None:
    """Chapter 12 Balanced: 'Reserve a minimum packet budget for each enabled channel, and compete
    for remaining space'. Channel 1's two small frames get in although channel 0 is served first
    and would fill the area under SharedOnly."""
    pending = {0: [68], 1: [12, 12]}
    shared = allocate(BudgetPolicy.SHARED_ONLY, 80, [0, 1], pending)
    assert dict(shared) == {0: 1, 1: 1} and shared.left == {1: 1}
    balanced = allocate(BudgetPolicy.BALANCED, 80, [0, 1], pending, reserve_bytes=24)
    assert dict(balanced) == {0: 0, 1: 2} and balanced.left == {0: 1}


def test_balanced_shares_the_rest() -> None:
    """Chapter 12: reserved_bytes = channels * reserve, shared_bytes = frame_area - reserved; a busy
    channel uses the shared part and idle channels' reserves."""
    alloc = allocate(BudgetPolicy.BALANCED, 3048, [0, 1, 2, 3], {2: [68] * 60})
    assert alloc[2] == 3048 // 68 and alloc.left == {2: 60 - 3048 // 68}


def test_deterministic_does_not_borrow() -> None:
    """Chapter 12 Deterministic: 'Allocate the budget evenly according to the enabled channels, and
    do not borrow between channels' -- 104 bytes over 4 channels is 26 each, even if three are idle."""
    alloc = allocate(BudgetPolicy.DETERMINISTIC, 104, [0, 1, 2, 3], {0: [12, 12, 12]})
    assert dict(alloc) == {0: 2, 1: 0, 2: 0, 3: 0} and alloc.left == {0: 1}
    assert allocate(BudgetPolicy.SHARED_ONLY, 104, [0, 1, 2, 3], {0: [12, 12, 12]})[0] == 3


def test_round_robin_and_rotation() -> None:
    """Chapter 12 'all frames share contention': one packet per channel per turn; ``rotate``
    decides which channel goes first, so a tie is not always won by channel 0."""
    pending = {0: [50, 50], 1: [50, 50]}
    assert dict(allocate(BudgetPolicy.SHARED_ONLY, 150, [0, 1], pending)) == {0: 2, 1: 1}
    assert dict(allocate(BudgetPolicy.SHARED_ONLY, 150, [0, 1], pending, rotate=1)) == {0: 1, 1: 2}


def test_disabled_channels_and_packet_limit() -> None:
    """Chapter 12 'enabled channels' / chapter 6 frame_count (one byte): channels outside the mask
    are not served nor counted; at most 255 packets per image."""
    alloc = allocate(BudgetPolicy.BALANCED, 3048, [1], {0: [4] * 10, 1: [4] * 300})
    assert dict(alloc) == {1: 255} and alloc.left == {1: 45}
    assert allocate(BudgetPolicy.BALANCED, 3048, [1], {1: [4] * 10}, max_packets=3)[1] == 3
    assert MAX_PACKETS == 255
    assert dict(allocate(BudgetPolicy.BALANCED, 100, [], {0: [4]})) == {}
    with pytest.raises(LocalError):
        allocate(BudgetPolicy.BALANCED, -1, [0], {})


def test_allocation_feeds_the_encoder() -> None:
    """Chapters 8.3 and 12: sizes from packet_size (ALIGN4 included) allocated to the TxPDO frame
    area always encode; what was left behind is what the device reports as STREAM_TRUNCATED."""
    layout = StreamLayout(multiplier=1, options=Option.ALIGN_4_ENABLE, direction=Direction.TX)
    queues = {ch: [CanPacket.of(ch, 0x100 + k, True, data=bytes(k % 9)) for k in range(6)] for ch in range(4)}
    alloc = allocate(layout.budget_policy, layout.frame_area_bytes, layout.channels,
                     {ch: [packet_size(p, layout) for p in q] for ch, q in queues.items()})
    chosen = [p for ch in layout.channels for p in queues[ch][:alloc[ch]]]
    assert alloc.truncated and alloc.taken == len(chosen)
    image = encode_stream(layout, 1, chosen, overflow_sat=alloc.left_behind)
    decoded = decode_stream(image, layout)
    assert decoded.header.payload_len == alloc.bytes_used <= layout.frame_area_bytes
    assert decoded.header.overflow_sat == alloc.left_behind


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(list(BudgetPolicy)), st.integers(0, 3048),
       st.lists(st.integers(0, 3), unique=True, max_size=4),
       st.dictionaries(st.integers(0, 3), st.lists(st.integers(4, 80), max_size=40)),
       st.integers(0, 100), st.integers(0, 300), st.integers(0, 7))
def test_budget_invariants(policy: BudgetPolicy, area: int, enabled: list[int], pending: dict[int, list[int]],
                           reserve: int, max_packets: int, rotate: int) -> None:
    """Chapter 12 for any queues: whole packets only, oldest first, never more than the area (or a
    Deterministic share), Balanced's reserve honoured, nothing left that would still have fit."""
    alloc = allocate(policy, area, enabled, pending, reserve, max_packets=max_packets, rotate=rotate)
    assert set(alloc) == set(enabled)
    used = 0
    for ch in enabled:
        sizes = pending.get(ch, [])
        k = alloc[ch]
        assert 0 <= k <= len(sizes)
        mine = sum(sizes[:k])
        used += mine
        assert alloc.left.get(ch, 0) == len(sizes) - k
        if policy is BudgetPolicy.DETERMINISTIC:
            assert mine <= area // len(enabled)
            if k < len(sizes) and alloc.taken < max_packets:
                assert mine + sizes[k] > area // len(enabled)
        if policy is BudgetPolicy.BALANCED:
            floor = min(reserve, area // len(enabled))
            fit = 0
            while fit < len(sizes) and sum(sizes[:fit + 1]) <= floor:
                fit += 1
            assert k >= min(fit, max_packets) or alloc.taken == max_packets
    assert used == alloc.bytes_used <= area
    assert alloc.taken <= max_packets
    assert alloc.truncated == (alloc.left_behind > 0)
    if policy is not BudgetPolicy.DETERMINISTIC and alloc.taken < max_packets:
        for ch in enabled:
            sizes = pending.get(ch, [])
            if alloc[ch] < len(sizes):
                assert sizes[alloc[ch]] > area - used      # work conserving: it really did not fit


def test_default_reserve_holds_one_classic_frame() -> None:
    """Chapter 12 'minimum packet budget': the default reserve takes one classic 8-byte frame in its
    largest form (extended id, full64 timestamp, ALIGN4)."""
    layout = StreamLayout(profile=1, options=Option.ALIGN_4_ENABLE, direction=Direction.TX)
    biggest = CanPacket.of(0, 0x1FFFFFFF, True, data=bytes(8), tsf=Tsf.FULL64, timestamp=1)
    assert packet_size(biggest, layout) == DEFAULT_RESERVE_BYTES
