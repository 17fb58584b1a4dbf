"""The MCAN channel configuration (manual 13.4): what a master asks for (:class:`ChannelSettings`),
the checked result the MCAN registers hold (:class:`ChannelRuntime`) and the build between them,
with the bit timing solved from the 80 MHz MCAN clock and the Message RAM layout that must fit
its 8 KiB per channel (RX FIFO0/FIFO1/buffers, TX elements, TX events, filters).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.ecanlite import bittiming
from gatewaylab.devices.ecanlite.bittiming import BitTiming, BitTimingError, Tdc
from gatewaylab.devices.ecanlite.mcan.filters import EMPTY_FILTER, FilterElement
from gatewaylab.devices.ecanlite.mcan.objects import CONFIG_DEFAULTS, EXT_LIST_MAX, STD_LIST_MAX

__all__ = [
    "DATA_SIZE_BYTES",
    "MESSAGE_RAM_WORDS",
    "TX_PAD",
    "ApplyStatus",
    "BuildError",
    "ChannelRuntime",
    "ChannelSettings",
    "NodeMode",
    "build",
    "ram_words",
]


#: Message RAM per channel, in 32-bit words (8 KiB): the manual's general CAN FD default layout
#: (RXF0 48, RXF1 12, RXB 12, TX 32, TXE 32, 64 B elements, 64 + 24 filters) fills it exactly.
MESSAGE_RAM_WORDS = 2048
#: Data size enum (0x800x:65/66/68/72) -> maximum data bytes of one Message RAM element.
DATA_SIZE_BYTES: tuple[int, ...] = (8, 12, 16, 20, 24, 32, 48, 64)
#: M_CAN pads a transmitted frame whose DLC exceeds the element's data field with 0xCC.
TX_PAD = 0xCC


class ApplyStatus(enum.IntEnum):
    """0x800x:02 / :04 'Apply status / Flash status' (13.4 channel commands and status)."""

    OK = 0
    FAIL = 1
    BUILD_FAIL = 3
    RUNTIME_FAIL = 4


class NodeMode(enum.IntEnum):
    """0x800x:08 node mode (13.4)."""

    NORMAL = 0
    RESTRICTED = 1
    INTERNAL_LOOPBACK = 2
    LISTEN = 3



@dataclass(frozen=True, slots=True)
class ChannelSettings:
    """What a master asked for: 0x800x values and the two filter lists (input of :func:`build`)."""

    values: Mapping[int, int]
    std_filters: tuple[FilterElement, ...] = ()
    ext_filters: tuple[FilterElement, ...] = ()

    @classmethod
    def defaults(cls) -> ChannelSettings:
        """The factory configuration (13.4 defaults, no filters)."""
        return cls(CONFIG_DEFAULTS, (EMPTY_FILTER,) * STD_LIST_MAX, (EMPTY_FILTER,) * EXT_LIST_MAX)

    def get(self, sub: int) -> int:
        """A value, the default when absent."""
        return int(self.values.get(sub, CONFIG_DEFAULTS.get(sub, 0)))


@dataclass(frozen=True, slots=True)
class ChannelRuntime:
    """An applied, checked configuration (what the MCAN registers hold)."""

    nominal: BitTiming
    data: BitTiming | None
    tdc: Tdc | None
    fd: bool
    node_mode: NodeMode
    auto_retransmit: bool
    transmit_pause: bool
    non_iso: bool
    std_filters: tuple[FilterElement, ...]
    ext_filters: tuple[FilterElement, ...]
    non_match_std: int
    non_match_ext: int
    reject_remote_std: bool
    reject_remote_ext: bool
    xidam: int
    rx_fifo0: int
    rx_fifo1: int
    rx_buffers: int
    rx_data_bytes: int
    #: Per store (FIFO0, FIFO1, RX buffers): element count, data bytes, overwrite mode (13.4 :61/:63).
    rx_sizes: tuple[int, int, int]
    rx_store_bytes: tuple[int, int, int]
    rx_overwrite: tuple[bool, bool, bool]
    tx_elements: int
    tx_data_bytes: int
    tx_queue_mode: bool
    tx_event_fifo: int
    ram_words: int
    settings: ChannelSettings

    @property
    def nominal_bitrate(self) -> int:
        """The nominal bit rate the controller runs at."""
        return self.nominal.bitrate

    @property
    def data_bitrate(self) -> int | None:
        """The data-phase bit rate (None for classic CAN)."""
        return self.data.bitrate if self.data is not None else None


class BuildError(GatewaylabError):
    """A configuration that cannot be applied; ``status`` is what 0x800x:02 reports."""

    def __init__(self, message: str, status: ApplyStatus) -> None:
        super().__init__(message, int(status))
        self.status = status


def _words(data_bytes: int) -> int:
    return 2 + data_bytes // 4


def ram_words(v: ChannelSettings) -> int:
    """Message RAM words of a layout: RX/TX elements (2 header words + data), TX events (2),
    standard filters (1), extended filters (2), for the full filter lists."""
    rx = (v.get(62) * _words(DATA_SIZE_BYTES[v.get(65)]) + v.get(64) * _words(DATA_SIZE_BYTES[v.get(66)])
          + v.get(67) * _words(DATA_SIZE_BYTES[v.get(68)]))
    tx = (v.get(70) + v.get(71)) * _words(DATA_SIZE_BYTES[v.get(72)])
    return rx + tx + 2 * v.get(73) + STD_LIST_MAX + 2 * EXT_LIST_MAX


def build(v: ChannelSettings) -> ChannelRuntime:
    """Check and convert requested settings; :class:`BuildError` with the 0x800x:02 status."""
    fail, build_fail = ApplyStatus.FAIL, ApplyStatus.BUILD_FAIL
    for sub, hi in ((7, 1), (8, 3), (36, 3), (37, 3), (61, 1), (63, 1), (69, 1), (74, 2), (85, 3)):
        if v.get(sub) > hi:
            raise BuildError(f"0x800x:{sub} = {v.get(sub)} outside 0..{hi}", fail)
    if v.get(81) < 1:
        raise BuildError("TSU prescaler must be at least 1", fail)
    if v.get(49) > STD_LIST_MAX or v.get(55) > EXT_LIST_MAX:
        raise BuildError("filter count above the list maximum", fail)
    fd = v.get(15) != 0
    try:
        if v.get(7) == 0:
            nominal = bittiming.solve(v.get(19), v.get(21), v.get(22))
            data = bittiming.solve_data(v.get(20), v.get(23), v.get(24)) if fd else None
        else:
            nominal = bittiming.manual(v.get(25), v.get(26), v.get(27), v.get(28))
            data = (bittiming.manual(v.get(29), v.get(30), v.get(31), v.get(32), bittiming.DATA, what="data")
                    if fd else None)
            if not nominal.exact or (data is not None and not data.exact):
                raise BitTimingError("manual timing does not divide the 80 MHz clock into an exact bit rate")
    except BitTimingError as exc:
        raise BuildError(str(exc), build_fail) from None
    tdc = bittiming.tdc(v.get(16) != 0, data, v.get(33), v.get(34)) if data is not None else None
    for sub in (65, 66, 68, 72):
        if v.get(sub) >= len(DATA_SIZE_BYTES):
            raise BuildError(f"0x800x:{sub} data size enum {v.get(sub)} outside 0..7", build_fail)
    for sub, hi in ((62, 64), (64, 64), (67, 64), (70, 32), (71, 32), (73, 32)):
        if v.get(sub) > hi:
            raise BuildError(f"0x800x:{sub} = {v.get(sub)} elements, at most {hi}", build_fail)
    if v.get(70) + v.get(71) > 32 or v.get(70) + v.get(71) == 0:
        raise BuildError("TX FIFO/queue plus dedicated buffers must be 1..32 elements", build_fail)
    if v.get(62) == 0:
        raise BuildError("RX FIFO0 needs at least one element", build_fail)
    words = ram_words(v)
    if words > MESSAGE_RAM_WORDS:
        raise BuildError(f"layout needs {words} Message RAM words, the channel has {MESSAGE_RAM_WORDS}", build_fail)
    return ChannelRuntime(
        nominal=nominal, data=data, tdc=tdc, fd=fd, node_mode=NodeMode(v.get(8)),
        auto_retransmit=v.get(18) == 0, transmit_pause=v.get(10) != 0, non_iso=v.get(9) != 0,
        std_filters=tuple(v.std_filters[:v.get(49)]), ext_filters=tuple(v.ext_filters[:v.get(55)]),
        non_match_std=v.get(36), non_match_ext=v.get(37), reject_remote_std=v.get(38) != 0,
        reject_remote_ext=v.get(39) != 0, xidam=v.get(40) & 0x1FFFFFFF,
        rx_fifo0=v.get(62), rx_fifo1=v.get(64), rx_buffers=v.get(67),
        rx_data_bytes=DATA_SIZE_BYTES[v.get(65)],
        rx_sizes=(v.get(62), v.get(64), v.get(67)),
        rx_store_bytes=(DATA_SIZE_BYTES[v.get(65)], DATA_SIZE_BYTES[v.get(66)], DATA_SIZE_BYTES[v.get(68)]),
        rx_overwrite=(v.get(61) == 1, v.get(63) == 1, False), tx_elements=v.get(70) + v.get(71),
        tx_data_bytes=DATA_SIZE_BYTES[v.get(72)], tx_queue_mode=v.get(69) == 1, tx_event_fifo=v.get(73),
        ram_words=words, settings=v)


