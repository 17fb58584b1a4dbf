"""Frame durations from the bit-count model documented in docs/bus.md, computed by hand here."""

import pytest

from gatewaylab.bus import CanFrame, frame_duration


def test_classic_11bit_8_bytes_at_1mbit() -> None:
    # g = 34 stuffable control bits, 64 data bits, 13 unstuffed tail bits,
    # worst-case stuff bits floor((34 + 64 - 1) / 4) = 24  ->  135 bits = 135 us at 1 Mbit/s.
    """docs/bus.md bit-count model, classic 11-bit frame, computed by hand below."""
    assert frame_duration(CanFrame(0x123, bytes(8)), 1_000_000) == pytest.approx(135e-6)


def test_classic_29bit_empty_at_500k() -> None:
    # g = 54, no data, 13 tail bits, floor(53 / 4) = 13 stuff bits -> 80 bits = 160 us at 500 kbit/s.
    """docs/bus.md bit-count model, classic 29-bit frame, computed by hand below."""
    assert frame_duration(CanFrame(0x1ABCDEF, b"", extended=True), 500_000) == pytest.approx(160e-6)


def test_remote_frame_has_no_data_bits_whatever_its_dlc() -> None:
    # 34 + 13 + floor(33 / 4) = 55 bits at 250 kbit/s = 220 us.
    """docs/bus.md: a remote frame carries no data field whatever its DLC (CAN 2.0 §3.1 'Remote frame')."""
    assert frame_duration(CanFrame(0x700, rtr=True, dlc=8), 250_000) == pytest.approx(220e-6)


def test_fd_64_bytes_with_bit_rate_switch() -> None:
    # nominal: 17 arbitration bits + floor(16/4)=4 stuff + 13 tail = 34 bits at 1 Mbit/s = 34 us
    # data:    ESI+DLC+512 = 517 bits + floor(517/4)=129 stuff + 4 stuff count + 21 CRC + 7 fixed = 678
    #          bits at 5 Mbit/s = 135.6 us
    """docs/bus.md CAN FD model: nominal and data phases at their own bit rates, computed by hand below."""
    frame = CanFrame(0x100, bytes(64), fd=True, brs=True)
    assert frame_duration(frame, 1_000_000, 5_000_000) == pytest.approx(34e-6 + 135.6e-6)


def test_fd_without_brs_runs_entirely_at_nominal_rate() -> None:
    # 12 bytes: data phase 5 + 96 = 101 + floor(101/4)=25 + 4 + 17 CRC + 6 fixed = 153; + 34 nominal
    """docs/bus.md CAN FD model: without BRS the data phase also runs at the nominal rate."""
    frame = CanFrame(0x100, bytes(12), fd=True)
    assert frame_duration(frame, 1_000_000, 5_000_000) == pytest.approx(187e-6)
