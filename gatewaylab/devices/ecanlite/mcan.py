"""The ECAN-Lite's CAN side: four MCAN channels on virtual buses and their CoE objects.

:class:`McanChannel` is one MCAN controller (manual 13.4) on a
:class:`~gatewaylab.bus.Controller`: its applied configuration (bit timing solved from the 80 MHz
MCAN clock, node mode, filters, Message RAM layout), the firmware RX cache and TX ring with the
0x8021..0x8024 data-path policies, the chapter-7 status word and the 0x9000 / 0x9020 details.
:class:`McanModel` holds the four channels plus the system objects (``system.py``), the flash
image (``flash.py``) and the FoE update (``ota.py``), lists every object it owns
(:meth:`McanModel.object_defs`) and wires their hooks into a slave's dictionary
(:meth:`McanModel.install`). Sans-I/O: the bus calls in on the injected clock; nothing sleeps.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.bus import (
    BusEvent,
    Controller,
    ErrorFrameEvent,
    ErrorKind,
    ErrorState,
    StateChangeEvent,
    TxAbortedEvent,
    TxDoneEvent,
)
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.ecanlite import bittiming
from gatewaylab.devices.ecanlite.bittiming import BitTiming, BitTimingError, Tdc
from gatewaylab.devices.ecanlite.ota import FirmwareVersion
from gatewaylab.ethercat.description import ObjectDef
from gatewaylab.od import Access, DataType, Entry, ObjectDictionary, SdoAbort, SdoAbortCode

#: The firmware a device runs before any OTA update (0xF000:05 = 0x0103, :06 = 0x2100).
FACTORY_VERSION = FirmwareVersion(1, 3, 0x2100)

if TYPE_CHECKING:
    from gatewaylab.devices.ecanlite.flash import FlashMedium
    from gatewaylab.devices.ecanlite.system import SystemModel
    from gatewaylab.ethercat.foe import FoeHandler
    from gatewaylab.ethercat.slave import Slave

U8, U16, U32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
RO, RW, WO = Access.RO, Access.RW, Access.WO

CHANNELS = 4
CONFIG_BASE = 0x8001        # 0x8001..0x8004 MCAN Channel Config
POLICY_BASE = 0x8021        # 0x8021..0x8024 MCAN Data Path Control
INFO_BASE = 0x9000          # 0x9000..0x9003 MCAN Channel Information
DIAG_BASE = 0x9020          # 0x9020..0x9023 MCAN Data Path Diagnostics
STD_LIST_MAX = 64
EXT_LIST_MAX = 24
#: 0xF000:28/29 firmware RX / TX cache maximum depth.
RX_CACHE_MAX = 32
TX_CACHE_MAX = 64
#: Message RAM per channel, in 32-bit words (8 KiB): the manual's general CAN FD default layout
#: (RXF0 48, RXF1 12, RXB 12, TX 32, TXE 32, 64 B elements, 64 + 24 filters) fills it exactly.
MESSAGE_RAM_WORDS = 2048
#: Data size enum (0x800x:65/66/68/72) -> maximum data bytes of one Message RAM element.
DATA_SIZE_BYTES: tuple[int, ...] = (8, 12, 16, 20, 24, 32, 48, 64)
#: M_CAN pads a transmitted frame whose DLC exceeds the element's data field with 0xCC.
TX_PAD = 0xCC


class TxResult(enum.IntEnum):
    """The TX_RESULT ResultCode values (manual chapter 10); stream.TxResultCode has the same."""

    OK = 0
    QUEUED = 1
    BUS_BUSY = 2
    INVALID_CHANNEL = 3
    TX_FIFO_FULL = 4
    BUS_OFF = 5


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


class EntryStatus(enum.IntEnum):
    """0x800x:47/48 filter entry status (13.4)."""

    OK = 0
    INDEX_INVALID = 1
    COMMAND_INVALID = 2


class ChannelState(enum.IntEnum):
    """Chapter 7 status word bits 0..2."""

    DISABLED = 0
    INIT = 1
    RUN = 2
    BUSOFF = 3
    ERROR = 4
    LISTEN = 5


class EventFlag(enum.IntFlag):
    """0x900x:12 latched channel event flags (gatewaylab's bit layout, docs/devices/ecanlite-mcan.md)."""

    WARNING = 0x01
    BUS_OFF = 0x02
    RX_PRESSURE = 0x04
    TX_PRESSURE = 0x08
    STATE_CHANGE = 0x10


class Degraded(enum.IntFlag):
    """0x9020:15 degraded state bits (0 = normal)."""

    RX_OVERFLOW = 0x01
    BUS_OFF = 0x02
    TX_CONGESTION = 0x04


# -- 0x8001..0x8004 rows (13.4), in subindex order -------------------------------------------------
Row = tuple[int, str, DataType, int, Access]
CONFIG_ROWS: tuple[Row, ...] = (
    (1, "Apply command", U8, 0, WO), (2, "Apply status", U8, 0, RO), (3, "Flash command", U8, 0, WO),
    (4, "Flash status", U8, 0, RO), (5, "Command sequence", U32, 0, RO), (6, "Command Pad0", U32, 0, RO),
    (7, "Bit timing mode", U8, 0, RW), (8, "Node mode", U8, 0, RW), (9, "Non-ISO enable", U8, 0, RW),
    (10, "Transmit pause", U8, 0, RW), (11, "Edge filter enable", U8, 0, RW),
    (12, "Protocol exception disable", U8, 0, RW), (13, "Wide message marker enable", U8, 0, RW),
    (14, "External timestamp use", U8, 0, RW), (15, "FD enable", U8, 1, RW), (16, "TDC enable", U8, 1, RW),
    (17, "Restricted mode disable", U8, 0, RW), (18, "Disable auto retransmission", U8, 0, RW),
    (19, "Nominal bitrate", U32, 500_000, RW), (20, "Data bitrate", U32, 5_000_000, RW),
    (21, "Nominal SP min", U16, 750, RW), (22, "Nominal SP max", U16, 875, RW),
    (23, "Data SP min", U16, 750, RW), (24, "Data SP max", U16, 875, RW),
    (25, "Nominal BRP", U16, 0, RW), (26, "Nominal TSEG1", U8, 0, RW), (27, "Nominal TSEG2", U8, 0, RW),
    (28, "Nominal SJW", U8, 0, RW), (29, "Data BRP", U16, 0, RW), (30, "Data TSEG1", U8, 0, RW),
    (31, "Data TSEG2", U8, 0, RW), (32, "Data SJW", U8, 0, RW), (33, "TDC offset", U8, 0, RW),
    (34, "TDC filter", U8, 0, RW),
    (36, "Accept non-match std", U8, 0, RW), (37, "Accept non-match ext", U8, 0, RW),
    (38, "Reject remote std", U8, 0, RW), (39, "Reject remote ext", U8, 0, RW),
    (40, "Ext ID mask", U32, 0x1FFFFFFF, RW), (41, "Std list max", U8, STD_LIST_MAX, RO),
    (42, "Ext list max", U8, EXT_LIST_MAX, RO), (43, "Std current index", U8, 0, RW),
    (44, "Ext current index", U8, 0, RW), (45, "Std entry cmd", U8, 0, RW), (46, "Ext entry cmd", U8, 0, RW),
    (47, "Std entry status", U8, 0, RO), (48, "Ext entry status", U8, 0, RO),
    (49, "Std filter count", U8, 0, RW), (50, "Std filter type", U8, 0, RW),
    (51, "Std filter action", U8, 0, RW), (52, "Std filter sync", U8, 0, RW), (53, "Std ID1", U32, 0, RW),
    (54, "Std ID2", U32, 0, RW), (55, "Ext filter count", U8, 0, RW), (56, "Ext filter type", U8, 0, RW),
    (57, "Ext filter action", U8, 0, RW), (58, "Ext filter sync", U8, 0, RW), (59, "Ext ID1", U32, 0, RW),
    (60, "Ext ID2", U32, 0, RW),
    (61, "RX FIFO0 op mode", U8, 0, RW), (62, "RX FIFO0 size", U8, 48, RW), (63, "RX FIFO1 op mode", U8, 0, RW),
    (64, "RX FIFO1 size", U8, 12, RW), (65, "RX FIFO0 data size", U8, 7, RW),
    (66, "RX FIFO1 data size", U8, 7, RW), (67, "RX buffer count", U8, 12, RW),
    (68, "RX buffer data size", U8, 7, RW), (69, "TX FIFO queue mode", U8, 0, RW),
    (70, "TX FIFO queue size", U8, 32, RW), (71, "TX dedicated buffer count", U8, 0, RW),
    (72, "TX buffer data size", U8, 7, RW), (73, "TX event FIFO size", U8, 32, RW),
    (74, "Timestamp selection", U8, 0, RW), (75, "Timestamp prescaler", U8, 0, RW), (76, "TSU enable", U8, 0, RW),
    (77, "TSU use external timebase", U8, 0, RW), (78, "TSU capture on SOF", U8, 0, RW),
    (79, "TSU enable 64-bit", U8, 0, RW), (80, "Pad2", U8, 0, RO), (81, "TSU prescaler", U16, 1, RW),
    (82, "TSU external timebase source", U8, 0, RW), (83, "TSU TBSEL option", U8, 0, RW),
    (84, "Timeout enable", U8, 0, RW), (85, "Timeout select", U8, 0, RW), (86, "Pad3", U16, 0, RO),
    (87, "Timeout period", U16, 0, RW),
)
CONFIG_DEFAULTS: Mapping[int, int] = MappingProxyType({r[0]: r[3] for r in CONFIG_ROWS})
#: Subindexes that are commands, status or the filter editing window: not part of a saved config.
_CONFIG_VOLATILE = frozenset({1, 2, 3, 4, 5, 6, 41, 42, 43, 44, 45, 46, 47, 48, 50, 51, 52, 53, 54,
                              56, 57, 58, 59, 60, 80, 86})
CONFIG_PERSISTED: tuple[int, ...] = tuple(r[0] for r in CONFIG_ROWS if r[0] not in _CONFIG_VOLATILE)

# -- 0x8021..0x8024 rows (13.2.2) --------------------------------------------------------------------
POLICY_ROWS: tuple[Row, ...] = (
    (1, "Enable", U8, 1, RW), (2, "Apply command", U8, 0, RW), (3, "Apply status", U8, 0, RO),
    (4, "RX drain budget min", U8, 0, RW), (5, "RX drain budget max", U8, 2, RW),
    (6, "RX budget policy", U8, 1, RW), (7, "RX cache depth", U8, 2, RW), (8, "RX overflow policy", U8, 1, RW),
    (9, "Critical frame policy", U16, 1, RW), (10, "CAN ID priority policy", U16, 0, RW),
    (11, "TX budget min", U8, 0, RW), (12, "TX budget max", U8, 4, RW), (13, "TX overflow policy", U8, 1, RW),
    (14, "Bus-off recovery policy", U8, 1, RW), (15, "Backoff base cycles", U16, 2, RW),
    (16, "Degraded threshold", U16, 64, RW), (17, "Reserved0", U32, 0, RW), (18, "Reserved1", U32, 0, RW),
    (19, "Reserved2", U32, 0, RW), (20, "Active control word", U32, 0, RO),
)
POLICY_DEFAULTS: Mapping[int, int] = MappingProxyType({r[0]: r[3] for r in POLICY_ROWS})
POLICY_PERSISTED: tuple[int, ...] = tuple(r[0] for r in POLICY_ROWS if r[0] not in (2, 3, 20))

INFO_ROWS: tuple[Row, ...] = (
    (1, "ECR raw", U32, 0, RO), (2, "PSR raw", U32, 0, RO), (3, "IR raw", U32, 0, RO),
    (4, "RXF0S raw", U32, 0, RO), (5, "RXF1S raw", U32, 0, RO), (6, "TXFQS raw", U32, 0, RO),
    (7, "TXEFS raw", U32, 0, RO), (8, "HPMS raw", U32, 0, RO), (9, "PDO channel status", U16, 0, RO),
    (10, "RX pending count", U16, 0, RO), (11, "TX pending count", U16, 0, RO),
    (12, "Channel event flags", U16, 0, RO), (13, "RX dropped counter", U32, 0, RO),
    (14, "TX backpressure counter", U32, 0, RO), (15, "Bus off counter", U32, 0, RO),
    (16, "Detail sequence", U32, 0, RO),
)
DIAG_ROWS: tuple[Row, ...] = (
    (1, "RX cache count", U16, 0, RO), (2, "RX cache high watermark", U16, 0, RO),
    (3, "RX drain last", U16, 0, RO), (4, "RX drain max", U16, 0, RO), (5, "RX dropped total", U32, 0, RO),
    (6, "RX dropped old", U32, 0, RO), (7, "RX dropped new", U32, 0, RO), (8, "RX dropped critical", U32, 0, RO),
    (9, "TxPDO consumed last", U16, 0, RO), (10, "TxPDO consumed max", U16, 0, RO),
    (11, "TX fifo full count", U32, 0, RO), (12, "TX stale dropped", U32, 0, RO), (13, "Bus off count", U32, 0, RO),
    (14, "Recovery attempts", U16, 0, RO), (15, "Degraded state", U16, 0, RO), (16, "Last error", U32, 0, RO),
    (17, "Service max cycles", U32, 0, RO), (18, "Service last cycles", U32, 0, RO),
    (19, "Reserved0", U32, 0, RO), (20, "Reserved1", U32, 0, RO),
)


def rows_object(index: int, name: str, rows: Sequence[Row]) -> ObjectDef:
    """An ObjectDef RECORD from (sub, name, type, default, access) rows (gaps allowed)."""
    return ObjectDef(index, name, subs=tuple((r[1], r[2], r[3], r[4]) for r in rows),
                     sub_indexes=tuple(r[0] for r in rows))


def _abort(code: SdoAbortCode, text: str) -> SdoAbort:
    return SdoAbort(code, text)


# -- frames, filters, configuration ----------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ReceivedFrame:
    """A frame the channel accepted: the frame, the bus receive instant (clock seconds) and the
    Message RAM store it sits in (0 RX FIFO0, 1 RX FIFO1, 2 RX buffers; 13.4 filter action)."""

    frame: CanFrame
    t: float
    fifo: int = 0


@dataclass(frozen=True, slots=True)
class FilterElement:
    """One standard or extended filter element (M_CAN SIDF / XIDF): type SFT/EFT (0 range,
    1 dual id, 2 classic id + mask, 3 disabled (std) / range without XIDAM (ext)), action
    SFEC/EFEC (0 disable, 1 FIFO0, 2 FIFO1, 3 reject, 4 priority, 5 priority + FIFO0,
    6 priority + FIFO1, 7 RX buffer), sync tag, ID1, ID2."""

    type: int = 0
    action: int = 0
    sync: int = 0
    id1: int = 0
    id2: int = 0


_EMPTY_FILTER = FilterElement()
#: Filter action (SFEC/EFEC) -> store: 0 RX FIFO0, 1 RX FIFO1, 2 RX buffer; absent = not stored.
_STORE_OF_ACTION: Mapping[int, int] = MappingProxyType({1: 0, 2: 1, 5: 0, 6: 1, 7: 2})
#: The RX stores of a channel: FIFO0, FIFO1, dedicated RX buffers.
RX_STORES = 3


def filter_match(f: FilterElement, can_id: int, extended: bool, xidam: int) -> bool:
    """Does the element match ``can_id`` (M_CAN acceptance filtering)?"""
    if f.action == 0:
        return False
    if extended:
        masked = can_id if f.type == 3 else can_id & xidam
        if f.type in (0, 3):
            return f.id1 <= masked <= f.id2
        if f.type == 1:
            return masked in (f.id1, f.id2)
        return (masked & f.id2) == (f.id1 & f.id2)
    if f.type == 0:
        return f.id1 <= can_id <= f.id2
    if f.type == 1:
        return can_id in (f.id1, f.id2)
    if f.type == 2:
        return (can_id & f.id2) == (f.id1 & f.id2)
    return False   # SFT 3: element disabled


@dataclass(frozen=True, slots=True)
class ChannelSettings:
    """What a master asked for: 0x800x values and the two filter lists (input of :func:`build`)."""

    values: Mapping[int, int]
    std_filters: tuple[FilterElement, ...] = ()
    ext_filters: tuple[FilterElement, ...] = ()

    @classmethod
    def defaults(cls) -> ChannelSettings:
        """The factory configuration (13.4 defaults, no filters)."""
        return cls(CONFIG_DEFAULTS, (_EMPTY_FILTER,) * STD_LIST_MAX, (_EMPTY_FILTER,) * EXT_LIST_MAX)

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


# -- 0x8021..0x8024 data-path policy ------------------------------------------------------------------
#: 0x802x:07 legacy enum -> depth, and back (13.2.2 RX cache depth table).
_DEPTH_OF = {0: 32, 1: 8, 2: 16, 3: 24, 8: 8, 16: 16, 24: 24, 32: 32}
_ENUM_OF_DEPTH = {32: 0, 8: 1, 16: 2, 24: 3}


@dataclass(frozen=True, slots=True)
class DataPathPolicy:
    """An applied 0x802x policy (13.2.2)."""

    enable: bool = True
    rx_drain_min: int = 0
    rx_drain_max: int = 2
    rx_budget_policy: int = 1
    #: 0x802x:07 as written: legacy enum 0..3 or explicit 8/16/24/32 (see :attr:`depth`).
    rx_cache_depth: int = 2
    rx_overflow: int = 1
    critical: int = 1
    id_priority: int = 0
    tx_budget_min: int = 0
    tx_budget_max: int = 4
    tx_overflow: int = 1
    busoff_recovery: int = 1
    backoff_base: int = 2
    degraded_threshold: int = 64

    @classmethod
    def from_values(cls, v: Mapping[int, int]) -> DataPathPolicy:
        """Check 0x802x values; ValueError says what is wrong (apply status 1)."""
        def g(sub: int) -> int:
            return int(v.get(sub, POLICY_DEFAULTS[sub]))
        for sub, hi in ((1, 1), (4, 8), (5, 8), (6, 3), (8, 3), (9, 2), (11, 8), (12, 8), (13, 3), (14, 3)):
            if g(sub) > hi:
                raise ValueError(f"0x802x:{sub} = {g(sub)} outside 0..{hi}")
        if g(4) > g(5) or g(11) > g(12):
            raise ValueError("budget min above budget max")
        if g(7) not in _DEPTH_OF:
            raise ValueError(f"RX cache depth {g(7)} is neither 0..3 nor 8/16/24/32")
        return cls(g(1) == 1, g(4), g(5), g(6), g(7), g(8), g(9), g(10), g(11), g(12), g(13),
                   g(14), g(15), g(16))

    @property
    def depth(self) -> int:
        """RX cache depth in frames."""
        return _DEPTH_OF[self.rx_cache_depth]

    @property
    def control_word(self) -> int:
        """0x802x:20 packed echo (13.2.2 bit table)."""
        return ((int(self.enable)) | (self.rx_drain_min & 0xF) << 4 | (self.rx_drain_max & 0xF) << 8
                | (self.rx_budget_policy & 3) << 12 | _ENUM_OF_DEPTH[self.depth] << 14
                | (self.rx_overflow & 3) << 16 | (self.critical & 3) << 18 | (self.tx_budget_min & 0xF) << 20
                | (self.tx_budget_max & 0xF) << 24 | (self.tx_overflow & 3) << 28
                | (self.busoff_recovery & 3) << 30)


# -- CANopen critical frames (0x802x:09) --------------------------------------------------------------
def is_critical(frame: CanFrame, policy: int) -> bool:
    """Critical-frame classes of 13.2.2: 1 'CANopen safety' = NMT (0x000), SYNC (0x080), EMCY
    (0x081..0x0FF) and NMT error control / heartbeat (0x701..0x77F); 2 'CANopen all' adds TIME
    (0x100), SDO (0x581..0x5FF, 0x601..0x67F) and LSS (0x7E4/0x7E5). Standard identifiers only."""
    if policy == 0 or frame.extended:
        return False
    cid = frame.can_id
    if cid == 0x000 or 0x080 <= cid <= 0x0FF or 0x701 <= cid <= 0x77F:
        return True
    return policy >= 2 and (cid == 0x100 or 0x581 <= cid <= 0x5FF or 0x601 <= cid <= 0x67F
                            or cid in (0x7E4, 0x7E5))


@dataclass
class ChannelCounters:
    """0x9000 / 0x9020 counters of one channel."""

    rx_high_watermark: int = 0
    rx_drain_last: int = 0
    rx_drain_max: int = 0
    rx_dropped_total: int = 0
    rx_dropped_old: int = 0
    rx_dropped_new: int = 0
    rx_dropped_critical: int = 0
    consumed_last: int = 0
    consumed_max: int = 0
    tx_fifo_full: int = 0
    tx_stale_dropped: int = 0
    bus_off: int = 0
    recovery_attempts: int = 0
    last_error: int = 0
    rx_policy_drops: int = 0
    tx_policy_refusals: int = 0
    error_log: int = 0
    detail_sequence: int = 0


# M_CAN register offsets (HPM MCAN = Bosch M_CAN 3.x) the register service knows.
REG = MappingProxyType({
    "ENDN": 0x0004, "DBTP": 0x000C, "TEST": 0x0010, "RWD": 0x0014, "CCCR": 0x0018, "NBTP": 0x001C,
    "TSCC": 0x0020, "TSCV": 0x0024, "TOCC": 0x0028, "TOCV": 0x002C, "ECR": 0x0040, "PSR": 0x0044,
    "TDCR": 0x0048, "IR": 0x0050, "IE": 0x0054, "ILS": 0x0058, "ILE": 0x005C, "GFC": 0x0080,
    "SIDFC": 0x0084, "XIDFC": 0x0088, "XIDAM": 0x0090, "HPMS": 0x0094, "RXF0C": 0x00A0, "RXF0S": 0x00A4,
    "RXF0A": 0x00A8, "RXBC": 0x00AC, "RXF1C": 0x00B0, "RXF1S": 0x00B4, "RXF1A": 0x00B8, "RXESC": 0x00BC,
    "TXBC": 0x00C0, "TXFQS": 0x00C4, "TXESC": 0x00C8, "TXBRP": 0x00CC, "TXBAR": 0x00D0, "TXBCR": 0x00D4,
    "TXBTO": 0x00D8, "TXBCF": 0x00DC, "TXEFC": 0x00F0, "TXEFS": 0x00F4, "TXEFA": 0x00F8,
})
#: 13.6 write whitelist.
WRITE_WHITELIST = frozenset({0x000C, 0x0010, 0x0014, 0x0018, 0x001C, 0x0048, 0x0050, 0x0054, 0x0058,
                             0x005C, 0x0080, 0x0090, 0x00A8, 0x00B8, 0x00D0, 0x00D4, 0x00F8})
# IR bits (M_CAN): RF0N 0, RF0F 2, RF0L 3, TC 9, TFE 11, PEA 27, PED 28, EP 23, EW 24, BO 25.
IR_RF0N, IR_RF0F, IR_RF0L, IR_HPM, IR_TC, IR_TFE = 1 << 0, 1 << 2, 1 << 3, 1 << 8, 1 << 9, 1 << 11
IR_RF1N, IR_RF1F, IR_RF1L = 1 << 4, 1 << 6, 1 << 7
#: IR new message / full / lost bits of FIFO0 and FIFO1 (RX buffers: DRX 19, no full/lost bits).
_IR_NEW, _IR_FULL, _IR_LOST = (IR_RF0N, IR_RF1N, 1 << 19), (IR_RF0F, IR_RF1F, 0), (IR_RF0L, IR_RF1L, 0)
IR_EP, IR_EW, IR_BO, IR_PEA, IR_PED = 1 << 23, 1 << 24, 1 << 25, 1 << 27, 1 << 28
#: PSR.LEC of an error kind: 2 form, 3 ack, 5 bit0, 6 crc.
_LEC = {ErrorKind.FORM: 2, ErrorKind.ACK: 3, ErrorKind.BIT: 5, ErrorKind.CRC: 6}


@dataclass
class _TxEntry:
    frame: CanFrame
    ref: object


class McanChannel:
    """One MCAN channel: controller configuration, RX cache, TX ring, status and details."""

    def __init__(self, index: int, clock: Clock, controller: Controller | None) -> None:
        self.index = index
        self.clock = clock
        self.controller = controller
        self.runtime: ChannelRuntime | None = None
        self.policy = DataPathPolicy()
        #: The requested filter lists as edited through the window (applied at the next apply).
        self.std_filters: list[FilterElement] = [_EMPTY_FILTER] * STD_LIST_MAX
        self.ext_filters: list[FilterElement] = [_EMPTY_FILTER] * EXT_LIST_MAX
        self.counters = ChannelCounters()
        self._rx: deque[ReceivedFrame] = deque()
        self._tx: deque[_TxEntry] = deque()
        #: The firmware TX ring: frames over this cycle's TX budget (0x802x:12), not yet in the MCAN.
        self._ring: deque[_TxEntry] = deque()
        self._tx_served = 0
        self._results: list[tuple[object, int]] = []
        self._events = EventFlag(0)
        self._detail_pending = False
        self._ir = 0
        self._hpms = 0
        self._lec = 0
        #: Frames of each RX store (FIFO0, FIFO1, RX buffers) in the cache; lost flags (RXFnS.RFnL).
        self._fill = [0] * RX_STORES
        self._lost = [False] * RX_STORES
        self._rx_recent_drop = False
        self._tx_recent_full = False
        self._degraded = Degraded(0)
        self._backoff_cycles = 0
        self._backoff_level = 0
        self._expert: dict[int, int] = {}
        #: 0x8030 fine bypass (13.2.3): TxPDO bit 2 MCAN_READ, RxPDO bit 4 TX_RING / bit 5 MCAN_WRITE.
        self.bypass_read = False
        self.bypass_write = False
        if controller is not None:
            controller.on_frame = self._on_frame
            controller.on_event = self._on_event

    def __repr__(self) -> str:
        return f"<McanChannel {self.index} {ChannelState(self.status_word() & 7).name}>"

    # -- contract properties ---------------------------------------------------------------------
    @property
    def enabled(self) -> bool:
        """A controller is attached (an unconnected channel is disabled) and a config is applied."""
        return self.controller is not None and self.runtime is not None

    @property
    def fd(self) -> bool:
        """The applied configuration is CAN FD."""
        return self.runtime is not None and self.runtime.fd

    @property
    def classic(self) -> bool:
        """The applied configuration is classic CAN."""
        return not self.fd

    # -- configuration ---------------------------------------------------------------------------
    def apply(self, settings: ChannelSettings) -> ApplyStatus:
        """Apply a configuration (0x800x:01 = 1): the old one stays when this one fails."""
        try:
            runtime = build(settings)
        except BuildError as exc:
            self.counters.last_error = int(exc.status)
            return exc.status
        try:
            self._activate(runtime)
        except GatewaylabError:
            self.counters.last_error = int(ApplyStatus.RUNTIME_FAIL)
            if self.runtime is not None:
                self._activate(self.runtime)
            return ApplyStatus.RUNTIME_FAIL
        self.runtime = runtime
        self._degraded &= ~Degraded.BUS_OFF
        return ApplyStatus.OK

    def _activate(self, rt: ChannelRuntime) -> None:
        """Program the controller: re-time it, FD, node mode, retransmission; a restart of the
        MCAN also ends bus-off (host recovery)."""
        c = self.controller
        if c is None:
            return
        bus = c.bus
        c.fd = rt.fd
        c.bitrate = rt.nominal_bitrate
        c.data_bitrate = rt.data_bitrate if rt.fd else None
        c.auto_retransmit = rt.auto_retransmit
        c.listen_only = rt.node_mode is NodeMode.LISTEN
        if rt.node_mode is NodeMode.INTERNAL_LOOPBACK:
            if c.connected:
                bus.disconnect(c)
        elif not c.connected and c in bus.controllers:
            bus.reconnect(c)
        self._apply_recovery()
        if c.state is ErrorState.BUS_OFF:
            c.recover()

    def release(self) -> None:
        """Let go of the controller (pin rotation, reset): queued frames not on the wire are taken
        back and reported as aborted (ResultCode 2), the callbacks unhooked."""
        c = self.controller
        if c is None:
            return
        on_wire = c.bus.on_wire
        busy = on_wire.frame if on_wire is not None and on_wire.sender is c else None
        for entry in list(self._tx):
            if entry.frame is busy:
                continue
            c.withdraw(entry.frame)
            self._tx.remove(entry)
            self._results.append((entry.ref, TxResult.BUS_BUSY))
        while self._ring:
            self._results.append((self._ring.popleft().ref, TxResult.BUS_BUSY))
        if busy is not None:
            for entry in list(self._tx):
                self._tx.remove(entry)
                self._results.append((entry.ref, TxResult.OK))
        if c.on_frame == self._on_frame:
            c.on_frame = None
        if c.on_event == self._on_event:
            c.on_event = None
        self.controller = None

    def bind(self, controller: Controller | None) -> None:
        """Take a controller (pin rotation): hook it and program the applied configuration."""
        self.controller = controller
        if controller is not None:
            controller.on_frame = self._on_frame
            controller.on_event = self._on_event
            if self.runtime is not None:
                self._activate(self.runtime)

    def apply_policy(self, policy: DataPathPolicy) -> None:
        """Apply a data-path policy (0x802x:02 = 1); also ends a degraded state and host recovery."""
        self.policy = policy
        self._degraded = Degraded(0)
        self.counters.rx_policy_drops = 0
        self.counters.tx_policy_refusals = 0
        self._backoff_cycles = self._backoff_level = 0
        while len(self._rx) > self._depth:
            self._fill[self._rx.popleft().fifo] -= 1
            self.counters.rx_dropped_old += 1
            self.counters.rx_dropped_total += 1
        self._apply_recovery()
        c = self.controller
        if c is not None and c.state is ErrorState.BUS_OFF:
            c.recover()

    def _apply_recovery(self) -> None:
        c = self.controller
        if c is not None:
            c.auto_recover = (not self.policy.enable) or self.policy.busoff_recovery in (1, 3)

    @property
    def _depth(self) -> int:
        return self.policy.depth if self.policy.enable else RX_CACHE_MAX

    def filters(self, extended: bool) -> list[FilterElement]:
        """The requested filter list being edited."""
        return self.ext_filters if extended else self.std_filters

    def settings_from(self, values: Mapping[int, int]) -> ChannelSettings:
        """Requested settings: ``values`` (0x800x) and the edited filter lists."""
        return ChannelSettings(MappingProxyType(dict(values)), tuple(self.std_filters), tuple(self.ext_filters))

    # -- receive path ----------------------------------------------------------------------------
    def _accept(self, frame: CanFrame) -> int:
        """The store an accepted frame goes to (0 FIFO0, 1 FIFO1, 2 RX buffer), -1 = not stored:
        the first matching element's action, else the non-match rule (0 FIFO0, 1 FIFO1, 2/3 reject)."""
        rt = self.runtime
        if rt is None:
            return -1
        ext = frame.extended
        if frame.rtr and (rt.reject_remote_ext if ext else rt.reject_remote_std):
            return -1
        for i, f in enumerate(rt.ext_filters if ext else rt.std_filters):
            if filter_match(f, frame.can_id, ext, rt.xidam):
                if f.action in (4, 5, 6):
                    # high priority message: HPMS FIDX 8..14, FLST 15, MSI 6..7 (0 none, 2 FIFO0, 3 FIFO1)
                    self._hpms = i << 8 | ext << 15 | (0, 2, 3)[f.action - 4] << 6
                    self._ir |= IR_HPM
                return _STORE_OF_ACTION.get(f.action, -1)
        rule = rt.non_match_ext if ext else rt.non_match_std
        return rule if rule < 2 else -1

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        self._lec = 0
        store = self._accept(frame)
        rt = self.runtime
        if store < 0 or rt is None:
            return
        size = rt.rx_store_bytes[store]
        if len(frame.data) > size:
            # M_CAN stores only the element's data field; the DLC stays: the rest reads as zero
            frame = replace(frame, data=frame.data[:size].ljust(len(frame.data), b"\0"))
        self._ir |= _IR_NEW[store]
        if self._fill[store] >= rt.rx_sizes[store]:
            # the Message RAM FIFO / buffers are full (13.4 :61/:63 op mode): blocking loses the new
            # frame (RFnL), overwrite gives up the oldest frame of that FIFO
            self._ir |= _IR_FULL[store]
            if rt.rx_overwrite[store] and self._fill[store]:
                rx = self._rx
                for i, old in enumerate(rx):
                    if old.fifo == store:
                        del rx[i]
                        self._fill[store] -= 1
                        break
                self._drop("rx_dropped_old", store)
            else:
                self._drop("rx_dropped_new", store)
                return
        self._store(ReceivedFrame(frame, t, store))

    def _drop(self, attr: str, store: int = 0) -> None:
        c = self.counters
        setattr(c, attr, getattr(c, attr) + 1)
        c.rx_dropped_total += 1
        c.rx_policy_drops += 1
        self._lost[store] = self._rx_recent_drop = True
        self._ir |= _IR_LOST[store]
        self._latch(EventFlag.RX_PRESSURE)
        p = self.policy
        if p.enable and p.rx_overflow == 3 and c.rx_policy_drops >= p.degraded_threshold:
            self._degraded |= Degraded.RX_OVERFLOW

    def _store(self, rf: ReceivedFrame) -> None:
        rx = self._rx
        fill = self._fill
        if len(rx) >= self._depth:
            self._ir |= IR_RF0F
            p = self.policy
            policy = p.rx_overflow if p.enable else 1
            if policy == 0:
                fill[rx.popleft().fifo] -= 1
                self._drop("rx_dropped_old")
            elif policy == 2 and is_critical(rf.frame, p.critical):
                for i, old in enumerate(rx):
                    if not is_critical(old.frame, p.critical):
                        del rx[i]
                        fill[old.fifo] -= 1
                        self._drop("rx_dropped_critical")
                        break
                else:
                    fill[rx.popleft().fifo] -= 1
                    self._drop("rx_dropped_old")
            else:
                self._drop("rx_dropped_new", rf.fifo)
                return
        rx.append(rf)
        fill[rf.fifo] += 1
        if len(rx) > self.counters.rx_high_watermark:
            self.counters.rx_high_watermark = len(rx)

    def drain_budget(self) -> int:
        """Frames one TxPDO build may take from the RX cache (0x802x:04..06): limited = the max
        budget, balanced = at least 2, performance = everything, adaptive = the max budget, or
        everything once the cache is half full. Disabled policy = everything."""
        p = self.policy
        if not p.enable or p.rx_budget_policy == 2:
            return RX_CACHE_MAX
        if p.rx_budget_policy == 3 and 2 * len(self._rx) >= self._depth:
            return RX_CACHE_MAX
        if p.rx_budget_policy == 0:
            return max(2, p.rx_drain_max)
        return p.rx_drain_max

    def peek(self, limit: int) -> Sequence[ReceivedFrame]:
        """The oldest received frames, at most ``limit`` and the drain budget (not removed)."""
        n = min(limit, self.drain_budget(), len(self._rx))
        if n <= 0 or self.bypass_read:
            return ()
        rx = self._rx
        return tuple(rx[i] for i in range(n))

    def consume(self, n: int) -> None:
        """Remove the ``n`` oldest frames (they went into a TxPDO)."""
        n = max(0, min(n, len(self._rx)))
        rx, fill = self._rx, self._fill
        for _ in range(n):
            fill[rx.popleft().fifo] -= 1
        c = self.counters
        c.rx_drain_last = c.consumed_last = n
        c.rx_drain_max = max(c.rx_drain_max, n)
        c.consumed_max = max(c.consumed_max, n)

    def pending_rx(self) -> int:
        """Frames waiting in the RX cache."""
        return len(self._rx)

    def pending_tx(self) -> int:
        """Frames handed to the channel and not finished (in the TX ring or the MCAN)."""
        return len(self._tx) + len(self._ring)

    # -- transmit path ---------------------------------------------------------------------------
    def submit(self, frame: CanFrame, ref: object = None) -> int:
        """Queue a frame for transmission: 0 = queued (its result comes from
        :meth:`take_tx_results`), else the TxResult to report at once."""
        c = self.controller
        rt = self.runtime
        if c is None or rt is None:
            return TxResult.INVALID_CHANNEL
        if rt.node_mode in (NodeMode.LISTEN, NodeMode.RESTRICTED):
            return TxResult.INVALID_CHANNEL
        if frame.fd and not rt.fd:
            return TxResult.INVALID_CHANNEL
        if self.bypass_write:
            self._results.append((ref, TxResult.OK))     # 0x8030 TX_RING / MCAN_WRITE bypass
            return TxResult.OK
        if c.state is ErrorState.BUS_OFF:
            return TxResult.BUS_OFF
        p = self.policy
        if self._backoff_cycles > 0:
            self._tx_full()
            return TxResult.TX_FIFO_FULL
        if len(self._tx) + len(self._ring) >= rt.tx_elements:
            policy = p.tx_overflow if p.enable else 0
            if policy == 1 and rt.node_mode is not NodeMode.INTERNAL_LOOPBACK and self._drop_oldest_tx(c):
                pass
            else:
                self._tx_full()
                if policy == 2:
                    self._backoff_level = min(self._backoff_level + 1, 6)
                    self._backoff_cycles = max(1, p.backoff_base) << (self._backoff_level - 1)
                return TxResult.TX_FIFO_FULL
        if len(frame.data) > rt.tx_data_bytes:
            frame = replace(frame, data=frame.data[:rt.tx_data_bytes].ljust(len(frame.data), bytes((TX_PAD,))))
        entry = _TxEntry(frame, ref)
        if p.enable and (self._ring or self._tx_served >= p.tx_budget_max):
            # 13.2.2 SI12: at most 'TX budget max' frames per cycle go to the MCAN; the rest wait in
            # the firmware TX ring (same capacity) for the next cycles (on_cycle), in order
            self._ring.append(entry)
            return TxResult.OK
        return self._to_mcan(entry)

    def _to_mcan(self, entry: _TxEntry) -> int:
        """Hand one frame to the MCAN TX FIFO/queue (one unit of this cycle's TX budget)."""
        c = self.controller
        rt = self.runtime
        if c is None or rt is None:
            return TxResult.INVALID_CHANNEL
        if rt.node_mode in (NodeMode.LISTEN, NodeMode.RESTRICTED):
            return TxResult.INVALID_CHANNEL
        if c.state is ErrorState.BUS_OFF:
            return TxResult.BUS_OFF
        frame = entry.frame
        self._tx_served += 1
        self._tx.append(entry)
        if rt.node_mode is NodeMode.INTERNAL_LOOPBACK:
            self.clock.call_soon(self._loopback, entry)
            return TxResult.OK
        try:
            if rt.tx_queue_mode:
                c.send_by_priority(frame)
            else:
                c.send(frame)
        except GatewaylabError:
            self._tx.pop()
            return TxResult.INVALID_CHANNEL
        return TxResult.OK

    def _tx_full(self) -> None:
        c = self.counters
        c.tx_fifo_full += 1
        c.tx_policy_refusals += 1
        self._tx_recent_full = True
        self._latch(EventFlag.TX_PRESSURE)
        p = self.policy
        if p.enable and p.tx_overflow == 3 and c.tx_policy_refusals >= p.degraded_threshold:
            self._degraded |= Degraded.TX_CONGESTION

    def _drop_oldest_tx(self, c: Controller) -> bool:
        """TX overflow policy 'drop oldest': the oldest frame not yet on the wire is given up."""
        for i, entry in enumerate(self._tx):
            if c.withdraw(entry.frame):
                del self._tx[i]
                self.counters.tx_stale_dropped += 1
                self._results.append((entry.ref, TxResult.TX_FIFO_FULL))
                return True
        if self._ring:
            entry = self._ring.popleft()
            self.counters.tx_stale_dropped += 1
            self._results.append((entry.ref, TxResult.TX_FIFO_FULL))
            return True
        return False

    def _loopback(self, entry: _TxEntry) -> None:
        if entry in self._tx:
            self._tx.remove(entry)
            self._results.append((entry.ref, TxResult.OK))
            self._ir |= IR_TC
            self._on_frame(entry.frame, self.clock.now())

    def _finish(self, frame: CanFrame, result: TxResult) -> None:
        for i, entry in enumerate(self._tx):
            if entry.frame is frame:
                del self._tx[i]
                self._results.append((entry.ref, result))
                return

    def take_tx_results(self) -> list[tuple[object, int]]:
        """Refs of frames finished since the last call, with their TxResult."""
        out, self._results = self._results, []
        return out

    # -- bus events ------------------------------------------------------------------------------
    def _latch(self, flag: EventFlag) -> None:
        if not self._events & flag:
            self._events |= flag
            self.counters.detail_sequence += 1
        self._detail_pending = True

    def _on_event(self, ev: BusEvent) -> None:
        if isinstance(ev, TxDoneEvent):
            self._lec = 0
            self._ir |= IR_TC
            self._finish(ev.frame, TxResult.OK)
        elif isinstance(ev, TxAbortedEvent):
            self._finish(ev.frame, TxResult.BUS_OFF if ev.reason == "bus-off" else TxResult.BUS_BUSY)
        elif isinstance(ev, ErrorFrameEvent):
            self._lec = _LEC.get(ev.kind, 7)
            self.counters.error_log = min(255, self.counters.error_log + 1)
            self._ir |= IR_PEA
        elif isinstance(ev, StateChangeEvent):
            self._state_changed(ev)

    def _state_changed(self, ev: StateChangeEvent) -> None:
        self._latch(EventFlag.STATE_CHANGE)
        if ev.new is ErrorState.ERROR_PASSIVE:
            self._ir |= IR_EP
            self._latch(EventFlag.WARNING)
        elif ev.new is ErrorState.BUS_OFF:
            self._ir |= IR_BO
            self._latch(EventFlag.BUS_OFF)
            self.counters.bus_off += 1
            p = self.policy
            policy = p.busoff_recovery if p.enable else 1
            if policy in (1, 2, 3):
                self.counters.recovery_attempts = min(0xFFFF, self.counters.recovery_attempts + 1)
            if policy == 2 and self.controller is not None:
                self.clock.call_soon(self.controller.recover)
            if policy == 3:
                self._degraded |= Degraded.BUS_OFF

    def on_cycle(self, t: float) -> None:
        """Per-cycle tick: a new TX budget (0x802x:12) serves the firmware TX ring; TX backoff
        counts down."""
        self._tx_served = 0
        ring = self._ring
        if ring:
            budget = self.policy.tx_budget_max if self.policy.enable else len(ring)
            while ring and self._tx_served < budget:
                entry = ring.popleft()
                code = self._to_mcan(entry)
                if code:
                    self._results.append((entry.ref, code))
        if self._backoff_cycles > 0:
            self._backoff_cycles -= 1
            if self._backoff_cycles == 0 and not self._tx_recent_full:
                self._backoff_level = 0

    # -- status ----------------------------------------------------------------------------------
    def state(self) -> ChannelState:
        """Chapter 7 state field."""
        c = self.controller
        rt = self.runtime
        if c is None:
            return ChannelState.DISABLED
        if rt is None:
            return ChannelState.INIT
        if c.state is ErrorState.BUS_OFF:
            return ChannelState.BUSOFF
        if rt.node_mode in (NodeMode.LISTEN, NodeMode.RESTRICTED):
            return ChannelState.LISTEN
        if c.state is ErrorState.ERROR_PASSIVE:
            return ChannelState.ERROR
        return ChannelState.RUN

    def _status(self) -> int:
        c = self.controller
        word = int(self.state())
        if self.fd:
            word |= 1 << 3
        if self._degraded or (c is not None and (c.state is not ErrorState.ERROR_ACTIVE
                                                  or c.tec >= 96 or c.rec >= 96)):
            word |= 1 << 4
        if c is not None and c.state is ErrorState.BUS_OFF:
            word |= 1 << 5
        if self._rx_recent_drop or 4 * len(self._rx) >= 3 * self._depth:
            word |= 1 << 6
        rt = self.runtime
        tx_cap = rt.tx_elements if rt is not None else 32
        if self._tx_recent_full or self._backoff_cycles or 4 * (len(self._tx) + len(self._ring)) >= 3 * tx_cap:
            word |= 1 << 7
        if self._detail_pending:
            word |= 1 << 8
        rxp, txp = len(self._rx), len(self._tx) + len(self._ring)
        if rxp > 7 or txp > 7:
            word |= 1 << 9
        return word | min(rxp, 7) << 10 | min(txp, 7) << 13

    def status_word(self) -> int:
        """The chapter-7 16-bit status word for this cycle's header (the 'recent overflow'
        pressure bits are reported once, then cleared)."""
        word = self._status()
        self._rx_recent_drop = self._tx_recent_full = False
        return word

    # -- registers (0x9000 and 0xA000) -------------------------------------------------------------
    def register(self, offset: int) -> int:
        """Read an MCAN register of this channel (offsets of :data:`REG`; others read 0)."""
        if offset in self._expert:
            return self._expert[offset]
        c = self.controller
        rt = self.runtime
        tec = c.tec if c is not None else 0
        rec = c.rec if c is not None else 0
        if offset == 0x0004:
            return 0x87654321
        if offset == 0x0040:      # ECR: TEC 0..7, REC 8..14, RP 15, CEL 16..23
            return (min(tec, 255) | min(rec, 127) << 8 | (rec > 127) << 15 | self.counters.error_log << 16)
        if offset == 0x0044:      # PSR: LEC 0..2, ACT 3..4 (1 idle), EP 5, EW 6, BO 7
            state = c.state if c is not None else ErrorState.ERROR_ACTIVE
            return (self._lec | 1 << 3 | (state is ErrorState.ERROR_PASSIVE) << 5
                    | (tec >= 96 or rec >= 96) << 6 | (state is ErrorState.BUS_OFF) << 7)
        if offset == 0x0050:
            ir = self._ir
            if c is not None:
                ir |= (c.state is ErrorState.ERROR_PASSIVE) * IR_EP | (c.state is ErrorState.BUS_OFF) * IR_BO
            if not self._tx:
                ir |= IR_TFE
            return ir
        if rt is None:
            return 0
        if offset == 0x001C:      # NBTP: NSJW 25..31, NBRP 16..24, NTSEG1 8..15, NTSEG2 0..6 (value - 1)
            n = rt.nominal
            return (n.sjw - 1) << 25 | (n.brp - 1) << 16 | (n.tseg1 - 1) << 8 | (n.tseg2 - 1)
        if offset == 0x000C:      # DBTP: TDC 23, DBRP 16..20, DTSEG1 8..12, DTSEG2 4..7, DSJW 0..3
            d = rt.data
            if d is None:
                return 0
            return ((rt.tdc is not None and rt.tdc.enabled) << 23 | (d.brp - 1) << 16 | (d.tseg1 - 1) << 8
                    | (d.tseg2 - 1) << 4 | (d.sjw - 1))
        if offset == 0x0048:
            return 0 if rt.tdc is None else rt.tdc.offset << 8 | rt.tdc.filter
        if offset == 0x0018:      # CCCR: INIT 0, MON 5, DAR 6, TEST 7, FDOE 8, BRSE 9, TXP 14, NISO 15
            return (int(c is not None and c.state is ErrorState.BUS_OFF)
                    | (rt.node_mode in (NodeMode.LISTEN, NodeMode.INTERNAL_LOOPBACK)) << 5
                    | (not rt.auto_retransmit) << 6 | (rt.node_mode is NodeMode.INTERNAL_LOOPBACK) << 7
                    | rt.fd << 8 | rt.fd << 9 | rt.transmit_pause << 14 | rt.non_iso << 15
                    | (rt.node_mode is NodeMode.RESTRICTED) << 2)
        if offset == 0x0010:
            return (rt.node_mode is NodeMode.INTERNAL_LOOPBACK) << 4
        if offset == 0x0080:      # GFC: RRFE 0, RRFS 1, ANFE 2..3, ANFS 4..5
            return (rt.reject_remote_ext | rt.reject_remote_std << 1 | rt.non_match_ext << 2
                    | rt.non_match_std << 4)
        if offset == 0x0084:
            return len(rt.std_filters) << 16
        if offset == 0x0088:
            return len(rt.ext_filters) << 16
        if offset == 0x0090:
            return rt.xidam
        if offset == 0x0094:
            return self._hpms
        if offset in (0x00A0, 0x00B0):      # RXFnC: FnS 16..22, FnOM 31
            fifo = int(offset == 0x00B0)
            return rt.rx_sizes[fifo] << 16 | rt.rx_overwrite[fifo] << 31
        if offset in (0x00A4, 0x00B4):      # RXFnS: FnFL 0..6, FnF 24, RFnL 25
            fifo = int(offset == 0x00B4)
            fill = self._fill[fifo]
            full = fill >= rt.rx_sizes[fifo] or (fifo == 0 and len(self._rx) >= self._depth)
            return min(fill, 127) | full << 24 | self._lost[fifo] << 25
        if offset == 0x00C0:      # TXBC: NDTB 16..21, TFQS 24..29, TFQM 30
            return (rt.tx_elements << 24) | rt.tx_queue_mode << 30
        if offset == 0x00C4:      # TXFQS: TFFL 0..5, TFQF 21
            free = max(0, rt.tx_elements - len(self._tx))
            return free | (free == 0) << 21
        if offset == 0x00F0:
            return rt.tx_event_fifo << 16
        return 0

    def write_register(self, offset: int, value: int) -> bool:
        """A whitelisted write (13.6); False = the channel cannot take this value (status 2).

        IR is write-1-to-clear. NBTP, DBTP, TDCR, CCCR, TEST, GFC and XIDAM re-program the running
        channel as the M_CAN register would (bit timing re-times the bus controller, CCCR/TEST set
        the node mode, FD, retransmission, GFC/XIDAM the global filter); 0x800x keeps the requested
        configuration, and its next apply (or a reset) programs that again. The other whitelisted
        registers (interrupt routing, acknowledges, TX buffer requests) are kept and read back."""
        value &= 0xFFFFFFFF
        if offset == 0x0050:
            self._ir &= ~value
            if value & IR_RF0L:
                self._lost[0] = False
            if value & IR_RF1L:
                self._lost[1] = False
            return True
        if offset not in _PROGRAMMING:
            self._expert[offset] = value
            return True
        rt = self.runtime
        if rt is None:
            return False          # nothing applied yet: no running channel to re-program
        try:
            new = _reprogram(rt, offset, value)
        except (BitTimingError, ValueError):
            return False
        try:
            self._activate(new)
        except GatewaylabError:
            self._activate(rt)
            return False
        self.runtime = new
        return True

    def info(self) -> dict[int, int]:
        """0x900x values by subindex (13.5)."""
        c = self.counters
        return {1: self.register(0x0040), 2: self.register(0x0044), 3: self.register(0x0050),
                4: self.register(0x00A4), 5: self.register(0x00B4), 6: self.register(0x00C4), 7: 0,
                8: self.register(0x0094),
                9: self._status(),
                10: min(len(self._rx), 0xFFFF), 11: min(self.pending_tx(), 0xFFFF), 12: int(self._events),
                13: c.rx_dropped_total, 14: c.tx_fifo_full, 15: c.bus_off, 16: c.detail_sequence}

    def take_events(self) -> int:
        """Read and clear the latched event flags (0x900x:12) and the detail_pending bit."""
        flags, self._events = int(self._events), EventFlag(0)
        self._detail_pending = False
        return flags

    def diagnostics(self) -> dict[int, int]:
        """0x902x values by subindex (13.2.5)."""
        c = self.counters
        return {1: len(self._rx), 2: c.rx_high_watermark, 3: c.rx_drain_last, 4: c.rx_drain_max,
                5: c.rx_dropped_total, 6: c.rx_dropped_old, 7: c.rx_dropped_new, 8: c.rx_dropped_critical,
                9: c.consumed_last, 10: c.consumed_max, 11: c.tx_fifo_full, 12: c.tx_stale_dropped,
                13: c.bus_off, 14: c.recovery_attempts, 15: int(self._degraded), 16: c.last_error,
                17: 0, 18: 0, 19: 0, 20: 0}

    def clear_diagnostics(self) -> None:
        """0xB000 bit 5: counters, latched flags and the degraded state back to zero."""
        self.counters = ChannelCounters()
        self._events = EventFlag(0)
        self._detail_pending = False
        self._degraded = Degraded(0)
        self._ir = 0
        self._lost = [False] * RX_STORES


#: Registers whose write re-programs the running channel (13.6 whitelist, M_CAN layout).
_PROGRAMMING = frozenset({0x000C, 0x0010, 0x0018, 0x001C, 0x0048, 0x0080, 0x0090})


def _reprogram(rt: ChannelRuntime, offset: int, v: int) -> ChannelRuntime:
    """The runtime after an M_CAN register write (fields as Bosch M_CAN: value - 1 encodings);
    BitTimingError / ValueError when the channel cannot run it."""
    if offset == 0x001C:      # NBTP: NSJW 25..31, NBRP 16..24, NTSEG1 8..15, NTSEG2 0..6
        nominal = bittiming.manual((v >> 16 & 0x1FF) + 1, (v >> 8 & 0xFF) + 1, (v & 0x7F) + 1, (v >> 25) + 1)
        return replace(rt, nominal=nominal)
    if offset == 0x000C:      # DBTP: TDC 23, DBRP 16..20, DTSEG1 8..12, DTSEG2 4..7, DSJW 0..3
        data = bittiming.manual((v >> 16 & 0x1F) + 1, (v >> 8 & 0x1F) + 1, (v >> 4 & 0xF) + 1, (v & 0xF) + 1,
                                bittiming.DATA, what="data")
        auto = bittiming.tdc(bool(v >> 23 & 1), data)
        old = rt.tdc
        tdc = Tdc(auto.enabled, old.offset if old else auto.offset, old.filter if old else auto.filter)
        return replace(rt, data=data, tdc=tdc)
    if offset == 0x0048:      # TDCR: TDCF 0..6, TDCO 8..14
        if rt.data is None:
            raise ValueError("TDCR needs a CAN FD data phase")
        enabled = rt.tdc.enabled if rt.tdc is not None else rt.data.bitrate >= bittiming.TDC_FORCED_BITRATE
        return replace(rt, tdc=Tdc(enabled, v >> 8 & 0x7F, v & 0x7F))
    if offset == 0x0018:      # CCCR: ASM 2, MON 5, DAR 6, TEST 7, FDOE 8, TXP 14, NISO 15
        fd = bool(v >> 8 & 1)
        if fd and rt.data is None:
            raise ValueError("FDOE without a data bit timing (write DBTP first)")
        loopback = bool(v >> 7 & 1) and rt.node_mode is NodeMode.INTERNAL_LOOPBACK
        mode = (NodeMode.INTERNAL_LOOPBACK if loopback else NodeMode.LISTEN if v >> 5 & 1
                else NodeMode.RESTRICTED if v >> 2 & 1 else NodeMode.NORMAL)
        return replace(rt, fd=fd, node_mode=mode, auto_retransmit=not v >> 6 & 1,
                       transmit_pause=bool(v >> 14 & 1), non_iso=bool(v >> 15 & 1))
    if offset == 0x0010:      # TEST: LBCK 4 (internal loopback; CCCR.TEST/MON are implied)
        if v >> 4 & 1:
            return replace(rt, node_mode=NodeMode.INTERNAL_LOOPBACK)
        return replace(rt, node_mode=NodeMode.NORMAL) if rt.node_mode is NodeMode.INTERNAL_LOOPBACK else rt
    if offset == 0x0080:      # GFC: RRFE 0, RRFS 1, ANFE 2..3, ANFS 4..5
        return replace(rt, reject_remote_ext=bool(v & 1), reject_remote_std=bool(v >> 1 & 1),
                       non_match_ext=v >> 2 & 3, non_match_std=v >> 4 & 3)
    return replace(rt, xidam=v & 0x1FFFFFFF)      # XIDAM


def _put(od: ObjectDictionary, index: int, values: Mapping[int, int]) -> None:
    keys = [(index, s) for s in values]
    od.put_many(keys, [v & 0xFFFFFFFF for v in values.values()])


class McanModel:
    """The four MCAN channels, the system objects, flash and FoE update of one ECAN-Lite."""

    def __init__(self, clock: Clock, controllers: Sequence[Controller | None],
                 flash_path: Path | FlashMedium | None = None, *, serial: int = 0,
                 hardware_revision: int = 0) -> None:
        """``flash_path``: the configuration flash file (the APP partition is ``PATH.app`` next to
        it), None for flash in memory, or a :class:`~.flash.FlashMedium` (e.g. the previous
        model's ``flash``, so a reset keeps an in-memory flash and firmware)."""
        from gatewaylab.devices.ecanlite.flash import FileFlash, MemoryFlash
        from gatewaylab.devices.ecanlite.ota import OtaError, unpack
        from gatewaylab.devices.ecanlite.system import SystemModel

        if len(controllers) > CHANNELS:
            raise ValueError(f"the ECAN-Lite has {CHANNELS} MCAN channels, got {len(controllers)} controllers")
        self.clock = clock
        ctrls = list(controllers) + [None] * (CHANNELS - len(controllers))
        #: The controller on each fixed pin group; logical channel k uses group (k + rotation) % 4.
        self.pins: tuple[Controller | None, ...] = tuple(ctrls)
        self.rotation = 0
        self.channels: list[McanChannel] = [McanChannel(k, clock, c) for k, c in enumerate(ctrls)]
        if flash_path is None:
            self.flash: FlashMedium = MemoryFlash()
        elif isinstance(flash_path, (str, Path)):
            self.flash = FileFlash(flash_path)
        else:
            self.flash = flash_path
        #: The running firmware: the installed APP package, else the factory firmware.
        self.version: FirmwareVersion = FACTORY_VERSION
        try:
            app = self.flash.read_app()
            if app is not None:
                self.version = unpack(app).version
        except (OSError, OtaError):
            pass
        self.system: SystemModel = SystemModel(self, serial=serial, hardware_revision=hardware_revision)
        self.od: ObjectDictionary | None = None
        self.system.power_on()

    # -- contract --------------------------------------------------------------------------------
    @property
    def version_string(self) -> str:
        """0x100A text: '1.3 build 0x2100' (the device's version_string format)."""
        return str(self.version)

    def object_defs(self) -> tuple[ObjectDef, ...]:
        """Every object this module owns (0x8000..0x8004, 0x8020..0x8024, 0x8030, 0x9000..0x9003,
        0x9020..0x9023, 0xA000..0xA003, 0xB000, 0xF000)."""
        out: list[ObjectDef] = []
        for k in range(CHANNELS):
            out.append(rows_object(CONFIG_BASE + k, f"MCAN{k} Channel Config", CONFIG_ROWS))
            out.append(rows_object(POLICY_BASE + k, f"MCAN{k} Data Path Control", POLICY_ROWS))
            out.append(rows_object(INFO_BASE + k, f"MCAN{k} Channel Information", INFO_ROWS))
            out.append(rows_object(DIAG_BASE + k, f"MCAN{k} Data Path Diagnostics", DIAG_ROWS))
        out.extend(self.system.object_defs())
        return tuple(sorted(out, key=lambda o: o.index))

    def install(self, slave: Slave | None, od: ObjectDictionary) -> None:
        """Put the running configuration into ``od`` and wire the hooks (validators, reactions,
        read hooks). Called from the device's ``SlaveApplication.setup_od``; again after a reset
        with the new dictionary (the same dictionary twice only refreshes the values)."""
        hook = od is not self.od
        self.od = od
        for ch in self.channels:
            k = ch.index
            rt_values = ch.runtime.settings.values if ch.runtime is not None else CONFIG_DEFAULTS
            _put(od, CONFIG_BASE + k, {s: rt_values.get(s, CONFIG_DEFAULTS[s]) for s in CONFIG_PERSISTED})
            _put(od, POLICY_BASE + k, self._policy_values(ch.policy))
            if not hook:
                continue
            od.add_validator(CONFIG_BASE + k, self._config_validator)
            od.add_reaction(CONFIG_BASE + k, self._config_reaction)
            od.add_reaction(POLICY_BASE + k, self._policy_reaction)
            od.on_read(INFO_BASE + k, self._info_read)
            od.on_read(DIAG_BASE + k, self._diag_read)
        self.system.install(slave, od, hook=hook)

    def on_cycle(self, t: float) -> None:
        """Per-cycle tick (TX backoff); call once per process data cycle."""
        for ch in self.channels:
            ch.on_cycle(t)

    def ota_handler(self, on_accepted: Callable[[], None]) -> FoeHandler:
        """The FoE handler for ``ecan_lite_app`` (password 0): a good package takes the new
        version and calls ``on_accepted`` (the device resets)."""
        return self.system.ota_handler(on_accepted)

    def rotate(self, rotation: int) -> None:
        """0x8000:12 CAN pin rotation: logical channel k moves to pin group (k + rotation) % 4."""
        rotation %= CHANNELS
        if rotation == self.rotation:
            return
        for ch in self.channels:
            ch.release()
        self.rotation = rotation
        for ch in self.channels:
            ch.bind(self.pins[(ch.index + rotation) % CHANNELS])

    def close(self) -> None:
        """The firmware stops (device reset): the controllers forget this model's callbacks and
        their queued frames."""
        for ch in self.channels:
            c = ch.controller
            if c is not None:
                if c.on_frame == ch._on_frame:
                    c.on_frame = None
                if c.on_event == ch._on_event:
                    c.on_event = None
                c.flush_tx()
            ch._tx.clear()
            ch._ring.clear()

    def reset(self) -> None:
        """A device reset (after an OTA update or 0x8000:01): channels restart from the flash image."""
        for ch in self.channels:
            ch.std_filters = [_EMPTY_FILTER] * STD_LIST_MAX
            ch.ext_filters = [_EMPTY_FILTER] * EXT_LIST_MAX
            ch.runtime = None
            ch.clear_diagnostics()
            ch._rx.clear()
            ch._fill = [0] * RX_STORES
        self.system.power_on()

    # -- settings <-> dictionary -----------------------------------------------------------------
    @staticmethod
    def _policy_values(p: DataPathPolicy) -> dict[int, int]:
        return {1: int(p.enable), 4: p.rx_drain_min, 5: p.rx_drain_max, 6: p.rx_budget_policy,
                7: p.rx_cache_depth, 8: p.rx_overflow,
                9: p.critical, 10: p.id_priority, 11: p.tx_budget_min, 12: p.tx_budget_max, 13: p.tx_overflow,
                14: p.busoff_recovery, 15: p.backoff_base, 16: p.degraded_threshold, 20: p.control_word}

    def config_values(self, k: int) -> dict[int, int]:
        """The requested 0x800x values of channel ``k`` (the dictionary's, or the active ones)."""
        od = self.od
        index = CONFIG_BASE + k
        if od is not None:
            return {s: int(od.values[(index, s)]) for s in CONFIG_DEFAULTS}
        ch = self.channels[k]
        base = ch.runtime.settings.values if ch.runtime is not None else CONFIG_DEFAULTS
        return {s: int(base.get(s, CONFIG_DEFAULTS[s])) for s in CONFIG_DEFAULTS}

    def policy_values(self, k: int) -> dict[int, int]:
        """The requested 0x802x values of channel ``k``."""
        od = self.od
        if od is not None:
            return {s: int(od.values[(POLICY_BASE + k, s)]) for s in POLICY_DEFAULTS}
        return self._policy_values(self.channels[k].policy)

    def apply_channel(self, k: int) -> ApplyStatus:
        """0x800x:01 = 1."""
        ch = self.channels[k]
        status = ch.apply(ch.settings_from(self.config_values(k)))
        self._publish_config_status(k, apply_status=status)
        return status

    def apply_policy(self, k: int) -> int:
        """0x802x:02 = 1: 0 OK, 1 fail (old policy kept)."""
        ch = self.channels[k]
        try:
            policy = DataPathPolicy.from_values(self.policy_values(k))
        except ValueError:
            status = 1
        else:
            ch.apply_policy(policy)
            status = 0
        if self.od is not None:
            _put(self.od, POLICY_BASE + k, {3: status, 20: ch.policy.control_word})
        return status

    def load_channel_settings(self, k: int, values: Mapping[int, int], std: Sequence[FilterElement] = (),
                              ext: Sequence[FilterElement] = ()) -> ApplyStatus:
        """Settings from flash or the factory defaults become channel ``k``'s requested
        configuration (dictionary and filter lists) and are applied."""
        ch = self.channels[k]
        ch.std_filters = (list(std) + [_EMPTY_FILTER] * STD_LIST_MAX)[:STD_LIST_MAX]
        ch.ext_filters = (list(ext) + [_EMPTY_FILTER] * EXT_LIST_MAX)[:EXT_LIST_MAX]
        full = {**CONFIG_DEFAULTS, **{s: int(values[s]) for s in CONFIG_PERSISTED if s in values}}
        if self.od is not None:
            _put(self.od, CONFIG_BASE + k, {s: full[s] for s in CONFIG_PERSISTED})
        status = ch.apply(ch.settings_from(full))
        self._publish_config_status(k, apply_status=status)
        return status

    def load_policy_values(self, k: int, values: Mapping[int, int]) -> int:
        """0x802x values from flash or the defaults become channel ``k``'s requested policy and
        are applied (0 OK, 1 fail: the old policy stays)."""
        full = {**POLICY_DEFAULTS, **{s: int(values[s]) for s in POLICY_PERSISTED if s in values}}
        if self.od is not None:
            _put(self.od, POLICY_BASE + k, {s: full[s] for s in POLICY_PERSISTED})
        ch = self.channels[k]
        try:
            ch.apply_policy(DataPathPolicy.from_values(full))
            status = 0
        except ValueError:
            status = 1
        if self.od is not None:
            _put(self.od, POLICY_BASE + k, {3: status, 20: ch.policy.control_word})
        return status

    def _publish_config_status(self, k: int, *, apply_status: int | None = None,
                               flash_status: int | None = None) -> None:
        if self.od is None:
            return
        index = CONFIG_BASE + k
        values: dict[int, int] = {5: (int(self.od.values[(index, 5)]) + 1) & 0xFFFFFFFF}
        if apply_status is not None:
            values[2] = int(apply_status)
        if flash_status is not None:
            values[4] = int(flash_status)
        _put(self.od, index, values)

    # -- hooks -------------------------------------------------------------------------------------
    def _config_validator(self, entry: Entry, value: Any) -> None:
        sub = entry.subindex
        if sub == 49 and int(value) > STD_LIST_MAX:
            raise _abort(SdoAbortCode.VALUE_TOO_HIGH, f"at most {STD_LIST_MAX} standard filters")
        if sub == 55 and int(value) > EXT_LIST_MAX:
            raise _abort(SdoAbortCode.VALUE_TOO_HIGH, f"at most {EXT_LIST_MAX} extended filters")

    def _config_reaction(self, entry: Entry, value: Any) -> None:
        k = entry.index - CONFIG_BASE
        sub = entry.subindex
        od = self.od
        assert od is not None
        if sub == 1:
            od.put(entry.index, 1, 0)
            if int(value) == 1:
                self.apply_channel(k)
            elif int(value) != 0:
                self._publish_config_status(k, apply_status=ApplyStatus.FAIL)
        elif sub == 3:
            od.put(entry.index, 3, 0)
            if int(value):
                status = self.system.channel_flash(k, int(value))
                self._publish_config_status(k, flash_status=status)
        elif sub in (45, 46):
            od.put(entry.index, sub, 0)
            self._entry_command(k, extended=sub == 46, cmd=int(value))

    def _entry_command(self, k: int, *, extended: bool, cmd: int) -> None:
        od = self.od
        assert od is not None
        index = CONFIG_BASE + k
        ch = self.channels[k]
        idx_sub, status_sub, base = (44, 48, 56) if extended else (43, 47, 50)
        current = int(od.values[(index, idx_sub)])
        limit = EXT_LIST_MAX if extended else STD_LIST_MAX
        lst = ch.filters(extended)
        if cmd == 0:
            status = EntryStatus.OK
        elif cmd not in (1, 2, 3):
            status = EntryStatus.COMMAND_INVALID
        elif current >= limit:
            status = EntryStatus.INDEX_INVALID
        else:
            status = EntryStatus.OK
            if cmd == 1:
                f = lst[current]
                _put(od, index, {base: f.type, base + 1: f.action, base + 2: f.sync, base + 3: f.id1,
                                 base + 4: f.id2})
            elif cmd == 2:
                g = od.values
                lst[current] = FilterElement(int(g[(index, base)]) & 3, int(g[(index, base + 1)]) & 7,
                                             int(g[(index, base + 2)]), int(g[(index, base + 3)]),
                                             int(g[(index, base + 4)]))
            else:
                lst[current] = _EMPTY_FILTER
        od.put(index, status_sub, int(status))

    def _policy_reaction(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 2:
            assert self.od is not None
            self.od.put(entry.index, 2, 0)
            k = entry.index - POLICY_BASE
            if int(value) == 1:
                self.apply_policy(k)
            elif int(value) != 0:
                _put(self.od, entry.index, {3: 1})

    def _info_read(self, index: int, subindex: int) -> None:
        assert self.od is not None
        ch = self.channels[index - INFO_BASE]
        values = ch.info()
        if subindex == 12:
            values[12] = ch.take_events()
        else:
            values.pop(12)
        _put(self.od, index, values)

    def _diag_read(self, index: int, subindex: int) -> None:
        assert self.od is not None
        _put(self.od, index, self.channels[index - DIAG_BASE].diagnostics())
