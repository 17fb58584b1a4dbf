"""What a master writes into the esd CAN-EtherCAT in PREOP, as values (manual 4.2.1, 5.1.5.5,
5.1.5.6, 5.1.5.9), and the queue layout it reads back from the mapping (5.1.3.7-5.1.3.11).

Pure values and encoders; :class:`~.gateway.EsdHost` writes them by SDO.

Bit rates (0xF800): either the 0xF800:02 'Baud rate' index of Table 6 (what the manual's init
command of 4.2.1 writes) or the 0xF800:05 'API-baud rate' of Tables 7-10, built with
:func:`api_table`, :func:`api_numerical`, :func:`api_register` or one of the constants
:data:`NTCAN_NO_BAUDRATE` / :data:`NTCAN_AUTOBAUD`; :func:`for_bitrate` picks the plain choice for
a rate in bit/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gatewaylab.bus.frame import MAX_EXT_ID, MAX_STD_ID
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esd_can_ethercat.bitrate import (
    INDEX_USE_API,
    NTCAN_AUTOBAUD,
    NTCAN_LISTEN_ONLY_MODE,
    NTCAN_NO_BAUDRATE,
    NTCAN_USER_BAUDRATE,
    NTCAN_USER_BAUDRATE_NUM,
    TABLE6,
    TABLE9,
)
from gatewaylab.devices.esd_can_ethercat.codec import input_size, output_size

__all__ = ["INDEX_USE_API", "NTCAN_AUTOBAUD", "NTCAN_LISTEN_ONLY_MODE", "NTCAN_NO_BAUDRATE",
           "NTCAN_USER_BAUDRATE", "NTCAN_USER_BAUDRATE_NUM", "BitRate", "EsdConfig", "FilterArea",
           "QueueLayout", "api_numerical", "api_register", "api_table", "for_bitrate"]

#: 0x8000:20 'Flags' bit 0: the 29-bit queues 0x7001/0x6001 (docs/decisions.md, esd CAN-EtherCAT).
FLAG_29BIT = 0x0001
#: 5.1.5.5 defaults: Rx / Tx queue 16 messages, local queues 1000.
DEFAULT_QUEUE = 16
DEFAULT_LOCAL_QUEUE = 1000
#: 0x8001 holds at most FFh areas (5.1.5.6 'm = max. FFh').
MAX_FILTER_AREAS = 255
#: 0x1A85 'CAN Status PDO' is 48 bits (5.1.3.9).
STATUS_PDO_BYTES = 6
_EXT_BIT = 0x80000000


# ------------------------------------------------------------------------------------- bit rates
@dataclass(frozen=True, slots=True)
class BitRate:
    """One 0xF800 setting: ``index`` for 0xF800:02 (Table 6 0..6, or FFh = 'use :05') and ``api``
    for 0xF800:05 (written only when ``index`` is FFh; the gateway ignores it otherwise)."""

    index: int = INDEX_USE_API
    api: int = NTCAN_NO_BAUDRATE

    @classmethod
    def table6(cls, index: int) -> BitRate:
        """0xF800:02 = ``index`` (Table 6: 0 = 1000, 1 = 800, 2 = 500, 3 = 250, 4 = 125, 5 = 100, 6 = 50 kbit/s)."""
        return cls(index=index)

    @classmethod
    def api_value(cls, value: int) -> BitRate:
        """0xF800:02 = FFh and 0xF800:05 = ``value`` (Tables 7-10)."""
        return cls(index=INDEX_USE_API, api=value)

    @classmethod
    def no_baudrate(cls) -> BitRate:
        """NTCAN_NO_BAUDRATE (7FFF FFFFh, the default): the gateway stays passive, off the bus."""
        return cls.api_value(NTCAN_NO_BAUDRATE)

    @classmethod
    def autobaud(cls) -> BitRate:
        """NTCAN_AUTOBAUD (00FF FFFEh): listen-only until two other nodes reveal a table rate."""
        return cls.api_value(NTCAN_AUTOBAUD)


def api_table(index: int, listen_only: bool = False) -> int:
    """API baud rate of a Table 9 index (UBR = UBRN = 0), with LOM for listen-only."""
    if not 0 <= index <= 0xFFFF:
        raise ConfigError(f"table index 0x{index:X} does not fit bits 0-15")
    return index | (NTCAN_LISTEN_ONLY_MODE if listen_only else 0)


def api_numerical(rate: int, listen_only: bool = False) -> int:
    """API baud rate with UBRN: ``rate`` in bit/s in bits 0-23 (Table 7)."""
    if not 0 < rate <= 0xFFFFFF:
        raise ConfigError(f"numerical bit rate {rate} does not fit bits 0-23")
    return NTCAN_USER_BAUDRATE_NUM | rate | (NTCAN_LISTEN_ONLY_MODE if listen_only else 0)


def api_register(can_br: int, listen_only: bool = False) -> int:
    """API baud rate with UBR: the AT91SAM9263 CAN_BR register value in bits 0-24 (Table 7)."""
    if not 0 <= can_br <= 0x01FFFFFF:
        raise ConfigError(f"CAN_BR value 0x{can_br:X} does not fit bits 0-24")
    return NTCAN_USER_BAUDRATE | can_br | (NTCAN_LISTEN_ONLY_MODE if listen_only else 0)


def for_bitrate(rate: int, listen_only: bool = False) -> BitRate:
    """The plain setting for ``rate`` bit/s: the Table 6 index of 0xF800:02 (4.2.1) when the rate
    is there and active; else the Table 9 index of the API baud rate; else a numerical rate (UBRN)."""
    if not listen_only:
        for index, table_rate in TABLE6.items():
            if table_rate == rate:
                return BitRate.table6(index)
    for index, table_rate in TABLE9.items():
        if table_rate == rate:
            return BitRate.api_value(api_table(index, listen_only))
    return BitRate.api_value(api_numerical(rate, listen_only))


# ------------------------------------------------------------------------------------- filter
@dataclass(frozen=True, slots=True)
class FilterArea:
    """One 0x8001 identifier area (5.1.5.6): frames with ``first <= id <= last`` pass; 29-bit
    areas set bits 31 and 63 ('For 29-Bit CAN identifiers bit 31 and 63 must be set')."""

    first: int
    last: int
    extended: bool = False

    def __post_init__(self) -> None:
        top = MAX_EXT_ID if self.extended else MAX_STD_ID
        if not 0 <= self.first <= self.last <= top:
            raise ConfigError(f"filter area 0x{self.first:X}..0x{self.last:X} is not within 0..0x{top:X}")

    @property
    def value(self) -> int:
        """The UINT64 of 0x8001:n: bytes 0-3 first identifier, bytes 4-7 last identifier."""
        ext = _EXT_BIT if self.extended else 0
        return (self.first | ext) | (self.last | ext) << 32

    @classmethod
    def from_value(cls, value: int) -> FilterArea:
        """The area a 0x8001 entry holds."""
        first, last = value & 0xFFFFFFFF, (value >> 32) & 0xFFFFFFFF
        return cls(first & ~_EXT_BIT, last & ~_EXT_BIT, bool(first & _EXT_BIT))


# ------------------------------------------------------------------------------------- config
@dataclass(frozen=True, slots=True)
class EsdConfig:
    """Everything :meth:`EsdHost.configure` writes in PREOP; the defaults are the gateway's
    (5.1.5.5, 5.1.5.6, 5.1.5.9) except the bit rate, which a master always sets."""

    bitrate: BitRate = field(default_factory=lambda: BitRate.table6(2))
    extended: bool = False                    # 0x8000:20 bit 0: 29-bit queues
    rx_queue: int = DEFAULT_QUEUE             # 0x8000:21 messages per Rx batch (inputs)
    tx_queue: int = DEFAULT_QUEUE             # 0x8000:22 messages per Tx batch (outputs)
    local_rx_queue: int = DEFAULT_LOCAL_QUEUE  # 0x8000:23
    local_tx_queue: int = DEFAULT_LOCAL_QUEUE  # 0x8000:24
    filters: tuple[FilterArea, ...] = ()      # 0x8001; empty: every frame passes
    status_pdo: bool = False                  # 0x1A85 assigned after 0x1A00 in 0x1C13

    def __post_init__(self) -> None:
        if len(self.filters) > MAX_FILTER_AREAS:
            raise ConfigError(f"0x8001 holds at most {MAX_FILTER_AREAS} areas, got {len(self.filters)}")
        for name in ("rx_queue", "tx_queue"):
            if not 0 <= getattr(self, name) <= 0xFF:
                raise ConfigError(f"{name} is a UINT8 (5.1.5.5), got {getattr(self, name)}")
        for name in ("local_rx_queue", "local_tx_queue"):
            if not 0 <= getattr(self, name) <= 0xFFFF:
                raise ConfigError(f"{name} is a UINT16 (5.1.5.5), got {getattr(self, name)}")

    @property
    def flags(self) -> int:
        """0x8000:20."""
        return FLAG_29BIT if self.extended else 0


@dataclass(frozen=True, slots=True)
class QueueLayout:
    """The process image as the mapping objects describe it (read back after configuring)."""

    extended: bool          # 0x1600 maps 0x7001 (29-bit) rather than 0x7000
    tx_messages: int        # 0x1600:00 - 3
    rx_messages: int        # 0x1A00:00 - 4
    status_pdo: bool        # 0x1A85 assigned after 0x1A00
    output_bytes: int       # sum of the bit lengths of 0x1600 / 8
    input_bytes: int        # of 0x1A00 (+ 0x1A85) / 8

    @property
    def status_offset(self) -> int | None:
        """Where the 0x1A85 bytes start in the inputs (right after 0x1A00), or None."""
        return input_size(self.extended, self.rx_messages) if self.status_pdo else None

    def consistent(self) -> bool:
        """The sizes agree with 5.1.3.7/5.1.3.8 (6 + T x 12/16 out, 8 + R x 10/14 in, + 6)."""
        extra = STATUS_PDO_BYTES if self.status_pdo else 0
        return (self.output_bytes == output_size(self.extended, self.tx_messages)
                and self.input_bytes == input_size(self.extended, self.rx_messages) + extra)
