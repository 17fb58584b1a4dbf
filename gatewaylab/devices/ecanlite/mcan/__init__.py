"""The ECAN-Lite's CAN side, one concept per module: :mod:`.objects` (the CoE object rows),
:mod:`.filters` (acceptance filtering), :mod:`.layout` (configuration and Message RAM layout),
:mod:`.datapath` (RX cache, TX ring, budgets and their bookkeeping), :mod:`.registers` (the
M_CAN register service) and :mod:`.channel` (one MCAN channel on a bus controller). The device
model that binds the four channels into a slave's dictionary is
:class:`gatewaylab.devices.ecanlite.model.McanModel`. The names below are the ones users import
from ``gatewaylab.devices.ecanlite.mcan``; the rest live in their modules.
"""

from gatewaylab.devices.ecanlite.mcan.channel import ChannelState, McanChannel
from gatewaylab.devices.ecanlite.mcan.datapath import DataPathPolicy, PolicyError, ReceivedFrame, is_critical
from gatewaylab.devices.ecanlite.mcan.filters import FilterElement
from gatewaylab.devices.ecanlite.mcan.layout import ApplyStatus, ChannelSettings, NodeMode
from gatewaylab.devices.ecanlite.mcan.registers import WRITE_WHITELIST

__all__ = [
    "WRITE_WHITELIST", "ApplyStatus", "ChannelSettings", "ChannelState", "DataPathPolicy",
    "FilterElement", "McanChannel", "NodeMode", "PolicyError", "ReceivedFrame", "is_critical",
]
