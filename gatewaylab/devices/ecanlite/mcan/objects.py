"""The MCAN channels' CoE object rows (manual 13.2.2, 13.4, 13.5): 0x8001..0x8004 channel config,
0x8021..0x8024 data-path control, 0x9000..0x9003 information, 0x9020..0x9023 diagnostics.

Data, not behaviour: (subindex, name, type, default, access) rows, their defaults and which
subindexes a flash image keeps. :mod:`.model` binds them into a slave's dictionary.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import MappingProxyType

from gatewaylab.ethercat.description import ObjectDef
from gatewaylab.od import Access, DataType

__all__ = [
    "CHANNELS",
    "CONFIG_BASE",
    "CONFIG_DEFAULTS",
    "CONFIG_PERSISTED",
    "CONFIG_ROWS",
    "DIAG_BASE",
    "DIAG_ROWS",
    "EXT_LIST_MAX",
    "INFO_BASE",
    "INFO_ROWS",
    "POLICY_BASE",
    "POLICY_DEFAULTS",
    "POLICY_PERSISTED",
    "POLICY_ROWS",
    "RX_CACHE_MAX",
    "STD_LIST_MAX",
    "TX_CACHE_MAX",
    "Row",
    "rows_object",
]


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

