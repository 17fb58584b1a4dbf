"""Hypothesis on random RxPDO images through the whole device (issue 10 'Tests', 13.2, 16.2): only
LastPDOError codes of the table come out, the counters move with every rejected image, and the bus
never sees a frame of a rejected image."""

from __future__ import annotations

import tempfile
from pathlib import Path

from ecanlite_device_kit import Rig, bring_up, make_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.devices.ecanlite.stream import CanPacket, Direction, PdoError, StreamLayout, crc16, encode_stream

N = 1
LAYOUT = StreamLayout(multiplier=N, direction=Direction.RX)
_RIG: list[Rig] = []


def _rig() -> Rig:
    if not _RIG:
        rig = make_rig(Path(tempfile.mkdtemp(prefix="ecan-prop-")))
        bring_up(rig, n=N)
        _RIG.append(rig)
    return _RIG[0]


def _fix_crc(image: bytearray) -> None:
    n = image[6] | image[7] << 8
    if 24 + n <= len(image):
        image[8:10] = crc16(image[24:24 + n]).to_bytes(2, "little")


@st.composite
def images(draw: st.DrawFn) -> bytes:
    """Mostly-valid images with a few random bytes changed (CRC repaired or not), or pure noise."""
    if draw(st.booleans()):
        return draw(st.binary(min_size=128 * N, max_size=128 * N))
    packets = draw(st.lists(st.builds(lambda ch, i, d: CanPacket.of(ch, i, data=d), st.integers(0, 3),
                                      st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=4))
    image = bytearray(encode_stream(LAYOUT, draw(st.integers(0, 0xFFFF)), packets))
    for _ in range(draw(st.integers(1, 4))):
        image[draw(st.integers(0, len(image) - 1))] = draw(st.integers(0, 255))
    if draw(st.booleans()):
        _fix_crc(image)
    return bytes(image)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(image=images())
def test_random_rxpdo_images_only_spec_errors_and_no_frame_from_a_rejected_image(image: bytes) -> None:
    """Each image: accepted (its frames may go out) or rejected with a LastPDOError of 13.2 counted in
    0x8011:15 and nothing submitted; torn or repeated images change nothing."""
    rig = _rig()
    app = rig.device.app
    before_errors = app.rx.errors
    before_submitted = app.frames_submitted
    rig.master.pdo_write(0, 0, image)
    rig.master.exchange_process_data()
    rig.clock.advance(0.002)
    if app.rx.errors != before_errors:
        assert app.rx.errors == before_errors + 1
        assert app.rx.last_error in {int(c) for c in PdoError} - {0}
        assert app.frames_submitted == before_submitted
    assert rig.device.slave.state.name == "OP"
