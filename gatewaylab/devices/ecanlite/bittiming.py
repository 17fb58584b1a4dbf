"""MCAN bit timing: the automatic solver and the manual-mode check (ECAN-Lite manual 13.4, 5.4.3 E).

Pure functions. The MCAN source clock is 80 MHz (0x8000:06..09). A bit is ``1 + TSEG1 + TSEG2``
time quanta of ``BRP`` clock periods; the sample point is ``(1 + TSEG1) / (1 + TSEG1 + TSEG2)``.
Sample points are in 0.1 % (875 = 87.5 %), as 0x800x:21..24 carry them.

The solver looks for an exact bit rate (no rounding: a rate the clock cannot divide exactly is
refused), a sample point inside ``[sp_min, sp_max]`` as close to the middle of the window as the
quanta allow, and among equally close ones the smallest prescaler (the most quanta per bit).
SJW is TSEG2 (clamped to the field's range), the usual choice for a robust resynchronisation.
"""

from __future__ import annotations

from dataclasses import dataclass

from gatewaylab.common.errors import ConfigError

__all__ = [
    "DATA",
    "MCAN_CLOCK_HZ",
    "NOMINAL",
    "TDC_FORCED_BITRATE",
    "BitTiming",
    "BitTimingError",
    "Limits",
    "Tdc",
    "manual",
    "solve",
    "solve_data",
    "tdc",
]


#: 0x8000:06..09 MCANk clock hz.
MCAN_CLOCK_HZ = 80_000_000
#: TDC is forced on at and above this data bit rate (13.4 TDC strategy, 14.3).
TDC_FORCED_BITRATE = 5_000_000


@dataclass(frozen=True, slots=True)
class Limits:
    """Field ranges of one phase (Bosch M_CAN NBTP / DBTP)."""

    brp: tuple[int, int]
    tseg1: tuple[int, int]
    tseg2: tuple[int, int]
    sjw: tuple[int, int]


#: NBTP: NBRP 1..512, NTSEG1 2..256, NTSEG2 2..128, NSJW 1..128.
NOMINAL = Limits((1, 512), (2, 256), (2, 128), (1, 128))
#: DBTP: DBRP 1..32, DTSEG1 1..32, DTSEG2 1..16, DSJW 1..16.
DATA = Limits((1, 32), (1, 32), (1, 16), (1, 16))


class BitTimingError(ConfigError):
    """No timing satisfies the request (apply status 3, 'build fail')."""


@dataclass(frozen=True, slots=True)
class BitTiming:
    """One phase's timing in MCAN register terms (the real values, not value - 1)."""

    brp: int
    tseg1: int
    tseg2: int
    sjw: int
    clock_hz: int = MCAN_CLOCK_HZ

    @property
    def tq_per_bit(self) -> int:
        """Time quanta per bit: sync segment + TSEG1 + TSEG2."""
        return 1 + self.tseg1 + self.tseg2

    @property
    def bitrate(self) -> int:
        """The bit rate this timing produces (integer division: exact for solver results)."""
        return self.clock_hz // (self.brp * self.tq_per_bit)

    @property
    def exact(self) -> bool:
        """The clock divides into exactly this bit rate."""
        return self.clock_hz % (self.brp * self.tq_per_bit) == 0

    @property
    def sample_point(self) -> int:
        """Sample point in 0.1 % (rounded)."""
        return (2000 * (1 + self.tseg1) + self.tq_per_bit) // (2 * self.tq_per_bit)


def _check(t: BitTiming, limits: Limits, what: str) -> None:
    for name, value, (lo, hi) in (("BRP", t.brp, limits.brp), ("TSEG1", t.tseg1, limits.tseg1),
                                  ("TSEG2", t.tseg2, limits.tseg2), ("SJW", t.sjw, limits.sjw)):
        if not lo <= value <= hi:
            raise BitTimingError(f"{what} {name} {value} outside {lo}..{hi}")
    if t.sjw > t.tseg2:
        raise BitTimingError(f"{what} SJW {t.sjw} larger than TSEG2 {t.tseg2}")


def solve(bitrate: int, sp_min: int, sp_max: int, limits: Limits = NOMINAL,
          clock_hz: int = MCAN_CLOCK_HZ, what: str = "nominal") -> BitTiming:
    """The automatic solution for ``bitrate`` with a sample point in ``[sp_min, sp_max]`` (0.1 %)."""
    if bitrate <= 0:
        raise BitTimingError(f"{what} bit rate {bitrate} must be positive")
    if not 0 < sp_min <= sp_max < 1000:
        raise BitTimingError(f"{what} sample point window {sp_min}..{sp_max} is not 1..999 with min <= max")
    target2 = sp_min + sp_max           # twice the middle of the window, in 0.1 %
    best: tuple[int, int, BitTiming] | None = None
    for brp in range(limits.brp[0], limits.brp[1] + 1):
        if clock_hz % (brp * bitrate):
            continue
        total = clock_hz // (brp * bitrate)
        if total < 1 + limits.tseg1[0] + limits.tseg2[0]:
            break                         # larger prescalers only give fewer quanta
        if total > 1 + limits.tseg1[1] + limits.tseg2[1]:
            continue
        for tseg2 in range(limits.tseg2[0], min(limits.tseg2[1], total - 1 - limits.tseg1[0]) + 1):
            tseg1 = total - 1 - tseg2
            if tseg1 > limits.tseg1[1]:
                continue
            sp_num = 1000 * (1 + tseg1)   # sample point * total, in 0.1 %
            if not sp_min * total <= sp_num <= sp_max * total:
                continue
            distance = abs(2 * sp_num - target2 * total) * 1_000_000 // total
            timing = BitTiming(brp, tseg1, tseg2, min(tseg2, limits.sjw[1]), clock_hz)
            key = (distance, brp)
            if best is None or key < best[:2]:
                best = (distance, brp, timing)
    if best is None:
        raise BitTimingError(f"no {what} timing for {bitrate} bit/s with a sample point in "
                             f"{sp_min / 10:g}..{sp_max / 10:g} % from a {clock_hz // 1_000_000} MHz clock")
    return best[2]


def solve_data(bitrate: int, sp_min: int, sp_max: int, clock_hz: int = MCAN_CLOCK_HZ) -> BitTiming:
    """The CAN FD data phase solution (DBTP ranges)."""
    return solve(bitrate, sp_min, sp_max, DATA, clock_hz, "data")


def manual(brp: int, tseg1: int, tseg2: int, sjw: int, limits: Limits = NOMINAL,
           clock_hz: int = MCAN_CLOCK_HZ, what: str = "nominal") -> BitTiming:
    """A manual timing (0x800x:25..32), checked against the field ranges."""
    timing = BitTiming(brp, tseg1, tseg2, sjw, clock_hz)
    _check(timing, limits, what)
    return timing


@dataclass(frozen=True, slots=True)
class Tdc:
    """Transmitter delay compensation as applied (TDCR and DBTP.TDC)."""

    enabled: bool
    offset: int
    filter: int


def tdc(enable: bool, data: BitTiming, offset: int = 0, filter_window: int = 0) -> Tdc:
    """13.4 TDC strategy: on at >= 5 Mbit/s whatever ``enable`` says; offset/filter 0 = automatic
    (the secondary sample point at the data sample point, in minimum time quanta: DBRP * (1 +
    DTSEG1), at most 127); non-zero values are kept as written."""
    on = enable or data.bitrate >= TDC_FORCED_BITRATE
    auto = min(127, data.brp * (1 + data.tseg1))
    return Tdc(on, offset or auto, filter_window or auto)
