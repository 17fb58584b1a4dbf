"""Bad input at the API raises a clear error and never corrupts the bus (issue 2, section 3)."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import FrameError


@pytest.mark.parametrize("kwargs, message", [
    ({"can_id": 0x100, "data": bytes(9)}, "DLC > 8"),
    ({"can_id": 0x800}, "out of range"),
    ({"can_id": 0x20000000, "extended": True}, "out of range"),
    ({"can_id": -1}, "out of range"),
    ({"can_id": 0x100, "data": bytes(13), "fd": True}, "matches no DLC"),
    ({"can_id": 0x100, "fd": True, "rtr": True}, "no remote frames"),
    ({"can_id": 0x100, "brs": True}, "only on CAN FD"),
    ({"can_id": 0x100, "rtr": True, "data": b"\x01"}, "carries no data"),
    ({"can_id": 0x100, "rtr": True, "dlc": 9}, "out of 0..8"),
    ({"can_id": 0x100, "data": b"\x01", "dlc": 2}, "does not match"),
])
def test_impossible_frames_are_refused(kwargs: dict, message: str) -> None:
    """Bad input at the API raises a clear error (issue 2 §3: DLC > 8 on classic CAN, no FD DLC for the length, id
    out of range, RTR on FD)."""
    with pytest.raises(FrameError, match=message):
        CanFrame(**kwargs)


def test_fd_frame_refused_on_a_classic_bus_and_bus_unharmed() -> None:
    """An FD frame on a classic bus raises a clear error and never corrupts the bus (issue 2 §3)."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "classic", 500_000)
    got: list[CanFrame] = []
    a = bus.attach("a")
    bus.attach("b", on_frame=lambda f, t: got.append(f))
    with pytest.raises(FrameError, match="classic CAN"):
        a.send(CanFrame(0x100, bytes(12), fd=True))
    a.send(CanFrame(0x100, b"ok"))
    clock.advance(0.01)
    assert got == [CanFrame(0x100, b"ok")]


def test_fd_payload_lengths_map_to_dlc() -> None:
    """CAN FD DLC 9..15 encode 12, 16, 20, 24, 32, 48, 64 bytes (ISO 11898-1:2015 DLC table; issue 2 §3)."""
    assert [CanFrame(1, bytes(n), fd=True).dlc for n in (8, 12, 16, 20, 24, 32, 48, 64)] == list(range(8, 16))


def test_python_can_message_round_trip() -> None:
    """Frames convert to python-can Messages and back without loss (FD flags, remote DLC)."""
    frame = CanFrame(0x1ABCDE, bytes(range(20)), extended=True, fd=True, brs=True, esi=True)
    assert CanFrame.from_message(frame.to_message(1.5)) == frame
    remote = CanFrame(0x7E5, rtr=True, dlc=8)
    assert CanFrame.from_message(remote.to_message()) == remote


@given(can_id=st.integers(-10, 0x2000_0010), data=st.binary(max_size=70), extended=st.booleans(),
       rtr=st.booleans(), fd=st.booleans(), brs=st.booleans(), esi=st.booleans(),
       dlc=st.integers(-1, 16))
def test_any_construction_is_a_valid_frame_or_a_frame_error(can_id, data, extended, rtr, fd, brs, esi, dlc) -> None:
    """Property: constructing a frame either yields a frame a bus accepts, or raises FrameError."""
    try:
        frame = CanFrame(can_id, data, extended, rtr, fd, brs, esi, dlc)
    except FrameError:
        return
    assert 0 <= frame.can_id <= (0x1FFFFFFF if extended else 0x7FF)
    assert frame.length <= (64 if fd else 8)
    clock = SimulatedClock()
    bus = VirtualBus(clock, "x", 1_000_000, 2_000_000)
    got: list[CanFrame] = []
    bus.attach("a").send(frame)
    bus.attach("b", on_frame=lambda f, t: got.append(f))
    clock.advance(0.01)
    assert got == [frame]


def test_to_message_keeps_the_channel_users_gave_python_can() -> None:
    """python-can's Message.channel is a name or a number (``can.Bus(0, interface=...)``, as python-can's own
    notifier_test does through the gatewaylab interface): both pass through, compiled or pure."""
    frame = CanFrame(0x123, b"\x01")
    assert frame.to_message(1.5, 0).channel == 0
    assert frame.to_message(1.5, "can0").channel == "can0"
    assert frame.to_message().channel is None
