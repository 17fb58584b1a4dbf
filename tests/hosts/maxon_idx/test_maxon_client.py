"""The host client against a scripted device (IDX guide 2.1.1.2, 2.1.1.3, 2.2.8 D, chapter 6)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from gatewaylab.devices.maxon_idx.codec import encode_frame
from gatewaylab.devices.maxon_idx.commands import InitiateSegmentedReadReply, Reply, SegmentReadReply
from gatewaylab.hosts.maxon_idx.client import IdxClient, IdxError


class ScriptedLink:
    """A Link that answers each written request with the next scripted reply."""

    def __init__(self, replies: Sequence[Reply]) -> None:
        self.replies = list(replies)
        self.sent: list[bytes] = []
        self.pending = b""

    def write(self, data: bytes) -> None:
        self.sent.append(data)
        if self.replies:
            self.pending += encode_frame(self.replies.pop(0).to_frame())

    def read(self, size: int, timeout: float) -> bytes:
        data, self.pending = self.pending[:size], self.pending[size:]
        return data

    def reset_input(self) -> None:
        self.pending = b""

    def close(self) -> None:
        pass


def test_segmented_read_stops_on_empty_segments_without_last_bit() -> None:
    """2.1.1.3: data ends with the last-segment bit; a device sending empty, non-last segments for
    ever does not hang the client."""
    link = ScriptedLink([InitiateSegmentedReadReply(0, 10, b"abc")] + [SegmentReadReply(0, t % 2 == 1, False, b"")
                                                                      for t in range(5)])
    with pytest.raises(IdxError, match="empty segment") as exc:
        IdxClient(link).read_segmented(2, 0x1008, 0)
    assert exc.value.code == 0x08000000
    assert len(link.sent) == 2


def test_segmented_read_checks_the_announced_total_length() -> None:
    """2.1.1.2: the initiate reply announces the object's total length; a last segment that leaves the
    data short is a length error (0x06070010), not a silently truncated value."""
    link = ScriptedLink([InitiateSegmentedReadReply(0, 10, b"abc"), SegmentReadReply(0, False, True, b"de")])
    with pytest.raises(IdxError, match="5 bytes received, 10 announced") as exc:
        IdxClient(link).read_segmented(2, 0x1008, 0)
    assert exc.value.code == 0x06070010


def test_segmented_read_checks_the_toggle() -> None:
    """2.1.1.3 + chapter 6: the reply's toggle bit echoes the request's; otherwise 0x05030000."""
    link = ScriptedLink([InitiateSegmentedReadReply(0, 10, b"abc"), SegmentReadReply(0, True, False, b"defg")])
    with pytest.raises(IdxError) as exc:
        IdxClient(link).read_segmented(2, 0x1008, 0)
    assert exc.value.code == 0x05030000 and exc.value.name == "Toggle error"
