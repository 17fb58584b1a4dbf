"""Object 0xF800 'CAN Bus Parameter' (manual 5.1.5.9): the baud rate index, the API baud rate
with its UBR / LOM / UBRN bits, the pre-defined table (Table 9), the special constants
(Table 10) and the bit timing the CAN controller derives from them (Figure 41).

A pure decoder: :func:`from_index` (0xF800:02) and :func:`from_api` (0xF800:05) turn a value into a
frozen :class:`BitRateSetting` or raise :class:`BitRateError` (answered with SDO abort 0x06090030).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from gatewaylab.common.errors import LocalError

__all__ = [
    "AUTOBAUD_ORDER",
    "CONTROLLER_CLOCK",
    "INDEX_USE_API",
    "NTCAN_AUTOBAUD",
    "NTCAN_LISTEN_ONLY_MODE",
    "NTCAN_NO_BAUDRATE",
    "NTCAN_USER_BAUDRATE",
    "NTCAN_USER_BAUDRATE_NUM",
    "TABLE6",
    "TABLE6_TO_API",
    "TABLE9",
    "BitRateError",
    "BitRateSetting",
    "BitTiming",
    "Mode",
    "from_api",
    "from_index",
    "no_baudrate",
    "table_rate",
    "timing_for",
    "timing_from_register",
]


#: 7.3 / 5.1.5.9: the CAN controller's clock ("CPU Master Clock: 120 MHz").
CONTROLLER_CLOCK = 120_000_000
NTCAN_NO_BAUDRATE = 0x7FFFFFFF
NTCAN_AUTOBAUD = 0x00FFFFFE
NTCAN_USER_BAUDRATE = 0x80000000      # UBR
NTCAN_LISTEN_ONLY_MODE = 0x40000000   # LOM
NTCAN_USER_BAUDRATE_NUM = 0x20000000  # UBRN
INDEX_USE_API = 0xFF

#: Table 6: 0xF800:02 'Baud rate' index -> bit/s (7, 8 'not allowed'; 255 = use 0xF800:05).
TABLE6 = {0: 1_000_000, 1: 800_000, 2: 500_000, 3: 250_000, 4: 125_000, 5: 100_000, 6: 50_000}
#: Table 6 index -> the Table 9 index of the same rate (what the driver's canSetBaudrate() gets).
TABLE6_TO_API = {0: 0x0, 1: 0xE, 2: 0x2, 3: 0x4, 4: 0x6, 5: 0x7, 6: 0x9}
#: Table 9: pre-defined bit rate table index -> bit/s (A..D 'not allowed': below the 50 kbit/s of 7.3).
TABLE9 = {0x0: 1_000_000, 0xE: 800_000, 0x1: 666_666, 0x2: 500_000, 0x3: 333_333, 0x4: 250_000,
          0x5: 166_666, 0x6: 125_000, 0x7: 100_000, 0x10: 83_333, 0x8: 66_666, 0x9: 50_000}
#: Automatic baud rate detection tries the table rates, fastest first (5.1.5.9 'Automatic Baud
#: Rate Detection': only the default bit rates of the esd table).
AUTOBAUD_ORDER = (0x0, 0xE, 0x1, 0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x10, 0x8, 0x9)
#: 7.3: "bit rate from 50 kBit/s up to 1 Mbit/s" (numerical rates, UBRN).
MIN_RATE, MAX_RATE = 50_000, 1_000_000


class BitRateError(LocalError):
    """A value 0xF800 does not accept."""


class Mode(enum.Enum):
    """How the CAN controller is set up."""

    NONE = "no baud rate"        # NTCAN_NO_BAUDRATE: passive, off the bus
    TABLE = "table"              # index into Table 9 (or Table 6 via 0xF800:02)
    NUMERICAL = "numerical"      # UBRN: bit/s as a number
    REGISTER = "register"        # UBR: the AT91SAM9263 CAN_BR register value
    AUTOBAUD = "autobaud"        # NTCAN_AUTOBAUD: detect, listen-only meanwhile


@dataclass(frozen=True, slots=True)
class BitTiming:
    """What the controller's bit timing gives (Figure 41 'CAN bitrate')."""

    bitrate: int            # actual bit/s
    time_quanta: int        # per bit
    before_sample: int      # time quanta before the sample point (incl. sync segment)
    prescaler: int

    @property
    def sample_point(self) -> float:
        """Position of the sample point in percent."""
        return 100.0 * self.before_sample / self.time_quanta

    @property
    def after_sample(self) -> int:
        """Time quanta after the sample point (phase segment 2)."""
        return self.time_quanta - self.before_sample


@dataclass(frozen=True, slots=True)
class BitRateSetting:
    """One decoded 0xF800 setting: the value as set, the mode, listen-only, the requested rate."""

    value: int                  # the API baud rate value (Figure 41 'Value set by canSetBaudrate()')
    mode: Mode
    listen_only: bool = False
    requested: int = 0          # bit/s asked for (0: none / autobaud)
    timing: BitTiming | None = None

    @property
    def bitrate(self) -> int:
        """The controller's actual bit rate (0 when off the bus or still detecting)."""
        return self.timing.bitrate if self.timing is not None else 0


def timing_for(rate: int) -> BitTiming:
    """Bit timing for ``rate`` on the 120 MHz controller clock: 20 time quanta with the sample point
    at 85 % when the clock divides evenly (Figure 41: 500 kbit/s = 20 tq, 17 before the sample
    point), else the quanta count 8..25 that divides evenly or comes closest."""
    best: tuple[float, int, int] | None = None
    for tq in (20, *range(25, 7, -1)):
        brp = max(1, round(CONTROLLER_CLOCK / (rate * tq)))
        actual = CONTROLLER_CLOCK / (brp * tq)
        err = abs(actual - rate)
        if best is None or err < best[0] - 1e-9:
            best = (err, tq, brp)
        if err < 1.0:  # table rates like 666.6 kbit/s are exact to a fraction of a bit/s
            break
    assert best is not None
    _err, tq, brp = best
    before = round(tq * 0.85)
    return BitTiming(int(CONTROLLER_CLOCK / (brp * tq)), tq, before, brp)


def timing_from_register(value: int) -> BitTiming:
    """AT91SAM9263 CAN_BR (5.1.5.9 'CAN BR of ARM9'): PHASE2 bits 0-2, PHASE1 4-6, PROPAG 8-10,
    SJW 12-13, BRP 16-22; a bit is 1 + (PROPAG+1) + (PHASE1+1) + (PHASE2+1) quanta of (BRP+1)/MCK."""
    phase2, phase1, propag, brp = value & 7, (value >> 4) & 7, (value >> 8) & 7, (value >> 16) & 0x7F
    tq = 4 + propag + phase1 + phase2
    return BitTiming(int(CONTROLLER_CLOCK / ((brp + 1) * tq)), tq, tq - (phase2 + 1), brp + 1)


def no_baudrate() -> BitRateSetting:
    """NTCAN_NO_BAUDRATE (the default 0xF800:05): passive on the bus."""
    return BitRateSetting(NTCAN_NO_BAUDRATE, Mode.NONE)


def table_rate(index: int, listen_only: bool = False, value: int | None = None) -> BitRateSetting:
    """A Table 9 index (0 = 1 Mbit/s, 0xE = 800 kbit/s, 2 = 500 kbit/s ...)."""
    rate = TABLE9.get(index)
    if rate is None:
        raise BitRateError(f"bit rate table index 0x{index:X} is not allowed")
    api = index | (NTCAN_LISTEN_ONLY_MODE if listen_only else 0)
    return BitRateSetting(api if value is None else value, Mode.TABLE, listen_only, rate, timing_for(rate))


def from_index(index: int) -> BitRateSetting | None:
    """0xF800:02 (Table 6): a table rate, or None for 0xFF ('as defined in API-baud rate')."""
    if index == INDEX_USE_API:
        return None
    if index not in TABLE6:
        raise BitRateError(f"baud rate index {index} is not allowed (0..6 or 255)")
    return table_rate(TABLE6_TO_API[index])


def from_api(value: int) -> BitRateSetting:
    """0xF800:05 'API-baud rate' (Tables 7, 8, 10)."""
    if value == NTCAN_NO_BAUDRATE:
        return no_baudrate()
    if value == NTCAN_AUTOBAUD:
        return BitRateSetting(value, Mode.AUTOBAUD, listen_only=True)
    ubr = bool(value & NTCAN_USER_BAUDRATE)
    lom = bool(value & NTCAN_LISTEN_ONLY_MODE)
    ubrn = bool(value & NTCAN_USER_BAUDRATE_NUM)
    if ubr and ubrn:
        raise BitRateError("UBR and UBRN cannot be set at the same time")
    if ubrn:
        if value & 0x1F000000:
            raise BitRateError(f"reserved bits set in 0x{value:08X}")
        rate = value & 0x00FFFFFF
        if not MIN_RATE <= rate <= MAX_RATE:
            raise BitRateError(f"numerical bit rate {rate} outside {MIN_RATE}..{MAX_RATE}")
        return BitRateSetting(value, Mode.NUMERICAL, lom, rate, timing_for(rate))
    if ubr:
        timing = timing_from_register(value & 0x01FFFFFF)
        if not 10_000 <= timing.bitrate <= MAX_RATE:
            raise BitRateError(f"CAN_BR 0x{value & 0x01FFFFFF:X} gives {timing.bitrate} bit/s")
        return BitRateSetting(value, Mode.REGISTER, lom, timing.bitrate, timing)
    if value & 0x1FFF0000:
        raise BitRateError(f"reserved bits set in 0x{value:08X}")
    return table_rate(value & 0xFFFF, lom, value)
