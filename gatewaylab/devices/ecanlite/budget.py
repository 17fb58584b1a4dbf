"""The multi-channel frame-area budget of the ECAN-Lite TxPDO (manual chapter 12).

The TxPDO has no fixed slot per CAN channel: every cycle the device fills one frame area of
``128*N - 24`` bytes from the pending packets of all enabled channels. :func:`allocate` is the one
scheduler, a pure function of packet sizes, so the device and the tests (and the benchmark) run
the same arithmetic:

- a packet goes into a cycle whole or not at all (chapter 12: "splitting across cycles is not
  allowed"); a channel's packets leave in order, so a packet that does not fit also holds back
  the ones behind it on that channel;
- whatever stays behind is reported (:attr:`Allocation.left_behind`), so the device sets
  STREAM_TRUNCATED, adds to overflow_sat and to the PDO overflow counter (0x8010:16).

Policies (0x8010:06): Balanced reserves ``reserve_bytes`` per enabled channel and lets the channels
compete for the rest; SharedOnly has no reserve; Deterministic splits the area evenly and never
lends one channel's share to another. Competition is round robin, one packet per channel per turn,
starting at a rotating channel so no channel is always first.
"""

from __future__ import annotations

import enum
from collections.abc import ItemsView, Iterator, KeysView, Mapping, Sequence
from dataclasses import dataclass
from typing import final

from gatewaylab.common.errors import LocalError

__all__ = ["DEFAULT_RESERVE_BYTES", "MAX_PACKETS", "Allocation", "BudgetPolicy", "allocate"]

#: Balanced's per-channel reserve: one classic 8-byte frame in every id / timestamp / ALIGN4
#: variant (2 ctrl + 4 ext id + 8 full64 + 8 data = 22, aligned 24). Chapter 12 names the reserve
#: but not its size (docs/decisions.md).
DEFAULT_RESERVE_BYTES = 24
#: frame_count is one byte (chapter 6): at most 255 packets per image.
MAX_PACKETS = 255


class BudgetPolicy(enum.IntEnum):
    """0x8010/0x8011:06 Budget policy (chapter 12); 3 is reserved and refused at apply."""

    BALANCED = 0
    SHARED_ONLY = 1
    DETERMINISTIC = 2


@final
@dataclass(frozen=True, slots=True)
class Allocation:
    """How many of each channel's oldest packets go into this cycle (read like a mapping channel ->
    count: ``alloc[ch]``, ``dict(alloc)``), plus what stayed behind, which the device reports as
    STREAM_TRUNCATED / overflow. Not a ``collections.abc.Mapping`` subclass: a compiled (mypyc)
    class cannot derive from an ABC; the mapping methods below are written out."""

    counts: Mapping[int, int]
    #: packets of enabled channels that did not fit this cycle, per channel (only channels > 0).
    left: Mapping[int, int]
    #: frame-area bytes the taken packets occupy.
    bytes_used: int

    @property
    def left_behind(self) -> int:
        """Packets of enabled channels left for a later cycle (0 = nothing truncated)."""
        return sum(self.left.values())

    @property
    def truncated(self) -> bool:
        """STREAM_TRUNCATED for this cycle: some pending packet did not fit."""
        return bool(self.left)

    @property
    def taken(self) -> int:
        """Packets placed in this cycle."""
        return sum(self.counts.values())

    def __getitem__(self, channel: int) -> int:
        return self.counts.get(channel, 0)

    def __iter__(self) -> Iterator[int]:
        return iter(self.counts)

    def __len__(self) -> int:
        return len(self.counts)

    def __contains__(self, channel: object) -> bool:
        return channel in self.counts

    def keys(self) -> KeysView[int]:
        """The enabled channels (``dict(alloc)`` reads them)."""
        return self.counts.keys()

    def items(self) -> ItemsView[int, int]:
        """(channel, count) pairs."""
        return self.counts.items()


def allocate(policy: BudgetPolicy | int, area_bytes: int, enabled_channels: Sequence[int],
             pending: Mapping[int, Sequence[int]], reserve_bytes: int = DEFAULT_RESERVE_BYTES, *,
             max_packets: int = MAX_PACKETS, rotate: int = 0) -> Allocation:
    """Split ``area_bytes`` among the pending packets of ``enabled_channels`` (chapter 12).

    ``pending`` maps a channel to the sizes of its waiting packets, oldest first (use
    :func:`~gatewaylab.devices.ecanlite.stream.packet_size`, which counts ALIGN4 padding).
    Channels missing from ``enabled_channels`` are not served and not counted as left behind.
    Pass the area left after what the device puts first (TX_RESULT packets) and ``max_packets``
    minus their number. ``rotate`` (e.g. the cycle counter) picks the channel served first in
    the shared competition. The result maps every enabled channel to its count.
    """
    if area_bytes < 0 or reserve_bytes < 0 or max_packets < 0:
        raise LocalError("area, reserve and packet limit must be >= 0")
    policy = BudgetPolicy(policy)
    channels = list(dict.fromkeys(enabled_channels))
    n = len(channels)
    counts = dict.fromkeys(channels, 0)
    if n == 0:
        return Allocation(counts, {}, 0)
    queues = [pending.get(ch, ()) for ch in channels]
    used = [0] * n
    room = max_packets
    if policy is BudgetPolicy.DETERMINISTIC:
        share = area_bytes // n
        for i, sizes in enumerate(queues):
            k, b = _take(sizes, 0, share, room)
            counts[channels[i]] = k
            used[i] = b
            room -= k
    else:
        total = area_bytes
        if policy is BudgetPolicy.BALANCED:
            reserve = min(reserve_bytes, area_bytes // n)
            for i, sizes in enumerate(queues):
                k, b = _take(sizes, 0, reserve, room)
                counts[channels[i]] = k
                used[i] = b
                room -= k
        free = total - sum(used)
        # Round robin, one packet per channel per turn; a channel whose next packet does not fit
        # drops out (its later packets may not overtake it).
        start = rotate % n
        order = [(start + j) % n for j in range(n)]
        active = [i for i in order if counts[channels[i]] < len(queues[i])]
        while active and room > 0:
            still = []
            for i in active:
                if room == 0:
                    break
                k = counts[channels[i]]
                size = queues[i][k]
                if size <= free:
                    free -= size
                    used[i] += size
                    room -= 1
                    counts[channels[i]] = k + 1
                    if k + 1 < len(queues[i]):
                        still.append(i)
            active = still
    left = {ch: len(queues[i]) - counts[ch] for i, ch in enumerate(channels) if len(queues[i]) > counts[ch]}
    return Allocation(counts, left, sum(used))


def _take(sizes: Sequence[int], start: int, budget: int, room: int) -> tuple[int, int]:
    """Oldest packets from ``start`` that fit ``budget`` bytes whole: (count, bytes)."""
    k = 0
    b = 0
    for size in sizes[start:]:
        if k >= room or b + size > budget:
            break
        b += size
        k += 1
    return k, b
