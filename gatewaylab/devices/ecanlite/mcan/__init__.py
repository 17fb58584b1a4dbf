"""The ECAN-Lite's CAN side, one concept per module: :mod:`.objects` (the CoE object rows),
:mod:`.filters` (acceptance filtering), :mod:`.layout` (configuration and Message RAM layout),
:mod:`.datapath` (RX cache, TX ring, budgets and their bookkeeping), :mod:`.registers` (the
M_CAN register service), :mod:`.channel` (one MCAN channel on a bus controller) and
:mod:`.model` (the four channels bound into a slave's dictionary). The names below are the
package's public surface, importable from ``gatewaylab.devices.ecanlite.mcan``.
"""

from gatewaylab.devices.ecanlite.mcan.channel import ChannelState, McanChannel
from gatewaylab.devices.ecanlite.mcan.datapath import (
    ChannelCounters,
    DataPath,
    DataPathPolicy,
    Degraded,
    EventFlag,
    PolicyError,
    ReceivedFrame,
    is_critical,
)
from gatewaylab.devices.ecanlite.mcan.filters import EntryStatus, FilterElement, filter_match
from gatewaylab.devices.ecanlite.mcan.layout import (
    DATA_SIZE_BYTES,
    MESSAGE_RAM_WORDS,
    ApplyStatus,
    BuildError,
    ChannelRuntime,
    ChannelSettings,
    NodeMode,
    build,
    ram_words,
)
from gatewaylab.devices.ecanlite.mcan.model import FACTORY_VERSION, McanModel
from gatewaylab.devices.ecanlite.mcan.objects import (
    CHANNELS,
    CONFIG_BASE,
    CONFIG_PERSISTED,
    CONFIG_ROWS,
    DIAG_BASE,
    EXT_LIST_MAX,
    INFO_BASE,
    POLICY_BASE,
    POLICY_PERSISTED,
    POLICY_ROWS,
    RX_CACHE_MAX,
    STD_LIST_MAX,
    TX_CACHE_MAX,
    Row,
    rows_object,
)
from gatewaylab.devices.ecanlite.mcan.registers import REG, WRITE_WHITELIST

__all__ = [
    "CHANNELS", "CONFIG_BASE", "CONFIG_PERSISTED", "CONFIG_ROWS", "DATA_SIZE_BYTES", "DIAG_BASE", "EXT_LIST_MAX",
    "FACTORY_VERSION", "INFO_BASE", "MESSAGE_RAM_WORDS", "POLICY_BASE", "POLICY_PERSISTED", "POLICY_ROWS", "REG",
    "RX_CACHE_MAX", "STD_LIST_MAX", "TX_CACHE_MAX", "WRITE_WHITELIST",
    "ApplyStatus", "BuildError", "ChannelCounters", "ChannelRuntime", "ChannelSettings", "ChannelState",
    "DataPath", "DataPathPolicy", "Degraded", "EntryStatus", "EventFlag", "FilterElement", "McanChannel",
    "McanModel", "NodeMode", "PolicyError", "ReceivedFrame", "Row", "build", "filter_match", "is_critical",
    "ram_words", "rows_object",
]
