"""Property tests: the drive's SDO server fed random requests of any length, classic and CAN FD, on the
product's own object dictionary (CiA 301 7.2.4 SDO, IDX guide table 6-20; issue 15: 'Property tests on
every decoder that reads bytes from outside ... the SDO server (frames into a Node)')."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.od import SdoAbortCode

NODE = 4
#: Every client command specifier of CiA 301 7.2.4.3 (initiate/segment download and upload, block).
CS = st.sampled_from([0x00, 0x10, 0x21, 0x23, 0x27, 0x2B, 0x2F, 0x40, 0x60, 0x70, 0x80, 0xA0, 0xA1, 0xA2,
                      0xA4, 0xC0, 0xC2, 0xC4, 0xC6, 0x01, 0x02, 0x81])
INDEX = st.sampled_from([0x1000, 0x1008, 0x1010, 0x1011, 0x1017, 0x1018, 0x1400, 0x1600, 0x1A00, 0x1F51,
                         0x2006, 0x30B0, 0x6040, 0x6060, 0x607A, 0x607D, 0x6099, 0x5FFF])


@st.composite
def request(draw: st.DrawFn) -> tuple[bytes, bool]:
    fd = draw(st.integers(0, 4)) == 0
    if draw(st.booleans()):
        data = draw(st.binary(max_size=64 if fd else 8))
    else:
        index = draw(INDEX)
        data = bytes([draw(st.one_of(CS, st.integers(0, 255))), index & 0xFF, index >> 8,
                      draw(st.integers(0, 9))]) + draw(st.binary(min_size=4, max_size=4))
        if fd:
            data += draw(st.binary(max_size=4))
    return data, fd


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(request(), st.sampled_from([0.0, 0.0005, 0.01, 1.2])), min_size=1, max_size=20))
def test_drive_sdo_server_answers_only_valid_frames(requests: list[tuple[tuple[bytes, bool], float]]) -> None:
    """Any request sequence (short, long, CAN FD, with pauses past the SDO timeout): the server never
    raises; every answer on 0x580+n is 8 bytes, aborts carry a table 6-20 code; afterwards an
    expedited upload of 0x1018:04 answers the drive's serial."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=1_000_000, data_bitrate=5_000_000)
    drive = Drive(clock, bus, NODE, 0x4004, "fuzzed")
    drive.start()
    out: list[CanFrame] = []
    ctrl = bus.attach("fuzzer", fd=True, on_frame=lambda f, t: out.append(f))
    clock.advance(0.01)
    for (data, fd), pause in requests:
        if fd:
            data = data.ljust(12, b"\0") if 8 < len(data) < 12 else data
            frame = CanFrame(0x600 + NODE, data.ljust(_fd_len(len(data)), b"\0"), fd=True)
        else:
            frame = CanFrame(0x600 + NODE, data)
        ctrl.send(frame)
        clock.advance(pause)
    clock.advance(2.0)
    for frame in out:
        if frame.can_id == 0x580 + NODE:
            assert len(frame.data) == 8, frame
            if frame.data[0] == 0x80:
                assert SdoAbortCode.known(int.from_bytes(frame.data[4:], "little")), frame
    out.clear()
    ctrl.send(CanFrame(0x600 + NODE, bytes([0x80, 0, 0, 0, 0, 0, 0, 0])))  # end whatever still runs
    clock.advance(0.01)
    out.clear()
    ctrl.send(CanFrame(0x600 + NODE, bytes([0x40, 0x18, 0x10, 0x04, 0, 0, 0, 0])))
    clock.advance(0.01)
    answers = [f.data for f in out if f.can_id == 0x580 + NODE]
    assert answers == [bytes([0x43, 0x18, 0x10, 0x04]) + (0x4004).to_bytes(4, "little")]


def _fd_len(n: int) -> int:
    for size in (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64):
        if size >= n:
            return size
    return 64
