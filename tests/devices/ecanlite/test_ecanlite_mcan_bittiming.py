"""Bit-timing solver of the MCAN channels (ECAN-Lite manual 13.4, 5.4.3 phase E, 14.3)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.devices.ecanlite import bittiming
from gatewaylab.devices.ecanlite.bittiming import BitTiming, BitTimingError, manual, solve, solve_data, tdc


@pytest.mark.parametrize(("rate", "sp_min", "sp_max", "want"), [
    # phase E: 1 Mbit/s nominal, peer at 87.5 % -> 80 tq of 12.5 ns, sample at tq 70
    (1_000_000, 875, 875, BitTiming(1, 69, 10, 10)),
    # 13.4 default 500 kbit/s with the default window 75.0..87.5 %: the middle, 81.25 %
    (500_000, 750, 875, BitTiming(1, 129, 30, 30)),
    # phase E text: a peer at 80.0 % nominal
    (1_000_000, 800, 800, BitTiming(1, 63, 16, 16)),
    # 250 kbit/s needs BRP 2 (320 tq would need TSEG1 279 > 256)
    (250_000, 875, 875, BitTiming(2, 139, 20, 20)),
])
def test_nominal_golden(rate: int, sp_min: int, sp_max: int, want: BitTiming) -> None:
    """13.4 'the firmware solves BRP/TSEG/SJW according to the MCAN source clock' (80 MHz,
    0x8000:06); 5.4.3 E8/E9 875..875 means exactly 87.5 %."""
    got = solve(rate, sp_min, sp_max)
    assert got == want
    assert got.bitrate == rate and got.exact
    assert sp_min <= got.sample_point <= sp_max


@pytest.mark.parametrize(("rate", "sp_min", "sp_max", "want"), [
    # phase E / 14.3: 5 Mbit/s data, 87.5 %: 16 tq, sample at 14
    (5_000_000, 875, 875, BitTiming(1, 13, 2, 2)),
    (5_000_000, 750, 875, BitTiming(1, 12, 3, 3)),
    (2_000_000, 800, 800, BitTiming(1, 31, 8, 8)),
])
def test_data_golden(rate: int, sp_min: int, sp_max: int, want: BitTiming) -> None:
    """13.4 SI20/23/24: CAN FD data phase from the same clock, DBTP ranges."""
    got = solve_data(rate, sp_min, sp_max)
    assert got == want
    assert got.bitrate == rate


def test_tdc_forced_at_5m() -> None:
    """13.4 TDC strategy: 'When the data segment reaches 5M or more, the firmware ignores TDC
    enable=0 and forcibly turns on TDC'; below 5M the master may turn it off; offset/filter 0 =
    automatic, non-zero kept."""
    five = solve_data(5_000_000, 875, 875)
    two = solve_data(2_000_000, 800, 800)
    assert tdc(False, five).enabled
    assert not tdc(False, two).enabled
    assert tdc(True, two).enabled
    auto = tdc(True, five)
    assert (auto.offset, auto.filter) == (14, 14)        # DBRP * (1 + DTSEG1): the data sample point
    assert (tdc(True, five, 9, 5).offset, tdc(True, five, 9, 5).filter) == (9, 5)


@pytest.mark.parametrize(("rate", "sp_min", "sp_max"), [
    (3_000_000, 875, 875),    # 80 MHz / 3 MHz is not an integer number of quanta... per BRP
    (1_000_000, 990, 999),    # no TSEG2 >= 2 leaves such a late sample point
    (0, 750, 875),
    (500_000, 875, 750),      # min above max
])
def test_unsolvable(rate: int, sp_min: int, sp_max: int) -> None:
    """13.4: an impossible request cannot be converted (apply status 3 'build fail')."""
    with pytest.raises(BitTimingError):
        solve(rate, sp_min, sp_max)


def test_manual_ranges() -> None:
    """13.4 SI25..32 manual mode: values are checked against the M_CAN field ranges."""
    t = manual(1, 69, 10, 10)
    assert t.bitrate == 1_000_000 and t.sample_point == 875
    with pytest.raises(BitTimingError):
        manual(0, 69, 10, 10)
    with pytest.raises(BitTimingError):
        manual(1, 13, 2, 3, bittiming.DATA)          # SJW above TSEG2
    with pytest.raises(BitTimingError):
        manual(1, 40, 2, 2, bittiming.DATA)          # DTSEG1 above 32


@given(st.integers(10_000, 8_000_000), st.integers(500, 950), st.integers(0, 100))
def test_solver_only_exact_in_window(rate: int, sp_min: int, width: int) -> None:
    """Any solution the solver gives is exact and inside the requested window (13.4)."""
    sp_max = min(999, sp_min + width)
    try:
        t = solve(rate, sp_min, sp_max)
    except BitTimingError:
        return
    assert t.exact and t.bitrate == rate
    assert sp_min * t.tq_per_bit <= 1000 * (1 + t.tseg1) <= sp_max * t.tq_per_bit
