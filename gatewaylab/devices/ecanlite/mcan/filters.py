"""MCAN acceptance filtering (manual 13.4 filter window, Bosch M_CAN SIDF/XIDF): the filter element,
the match rule, and which Message RAM store (RX FIFO0, RX FIFO1, RX buffers) an accepted frame
goes to. Pure functions of the applied configuration; the channel keeps the lists being edited.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING

from gatewaylab.bus.frame import CanFrame

if TYPE_CHECKING:
    from gatewaylab.devices.ecanlite.mcan.layout import ChannelRuntime

__all__ = ["EMPTY_FILTER", "RX_STORES", "STORE_OF_ACTION", "EntryStatus", "FilterElement", "accept", "filter_match"]


class EntryStatus(enum.IntEnum):
    """0x800x:47/48 filter entry status (13.4)."""

    OK = 0
    INDEX_INVALID = 1
    COMMAND_INVALID = 2



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


EMPTY_FILTER = FilterElement()
#: Filter action (SFEC/EFEC) -> store: 0 RX FIFO0, 1 RX FIFO1, 2 RX buffer; absent = not stored.
STORE_OF_ACTION: Mapping[int, int] = MappingProxyType({1: 0, 2: 1, 5: 0, 6: 1, 7: 2})
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



def accept(rt: ChannelRuntime, frame: CanFrame) -> tuple[int, int]:
    """Acceptance filtering of one received frame: (store, HPMS). The store is 0 RX FIFO0, 1 RX FIFO1,
    2 RX buffer, -1 not stored: the first matching element's action, else the non-match rule (0 FIFO0,
    1 FIFO1, 2/3 reject). HPMS is the high-priority message status a priority action (4..6) latches
    (FIDX 8..14, FLST 15, MSI 6..7: 0 none, 2 FIFO0, 3 FIFO1), else -1."""
    ext = frame.extended
    if frame.rtr and (rt.reject_remote_ext if ext else rt.reject_remote_std):
        return -1, -1
    for i, f in enumerate(rt.ext_filters if ext else rt.std_filters):
        if filter_match(f, frame.can_id, ext, rt.xidam):
            hpms = i << 8 | ext << 15 | (0, 2, 3)[f.action - 4] << 6 if f.action in (4, 5, 6) else -1
            return STORE_OF_ACTION.get(f.action, -1), hpms
    rule = rt.non_match_ext if ext else rt.non_match_std
    return (rule if rule < 2 else -1), -1
