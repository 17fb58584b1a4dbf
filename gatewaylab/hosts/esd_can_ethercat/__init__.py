"""Master-side library for the esd CAN-EtherCAT: the MDP 5000 counter
handshake of manual 5.1.5 written once, on any :class:`~gatewaylab.hosts.ethercat.backend.MasterBackend`.

``config`` (what a master writes in PREOP: 0xF800, 0x8000, 0x8001, 0x1C13; the layout it reads
back), ``handshake`` (the sans-I/O counter handshake on the process image bytes), ``gateway``
(:class:`EsdHost`: configure, cycle, send / receive, status, statistics), ``api``
(:class:`EsdQueueApi`: that API as a Protocol, for a second implementation on another gateway). The byte layouts are the
device's codec (``..codec``), shared by both sides.
"""

from gatewaylab.devices.esd_can_ethercat.codec import CanStatus
from gatewaylab.hosts.esd_can_ethercat.api import EsdQueueApi
from gatewaylab.hosts.esd_can_ethercat.config import (
           BitRate,
           EsdConfig,
           FilterArea,
           QueueLayout,
           api_numerical,
           api_register,
           api_table,
           for_bitrate,
)
from gatewaylab.hosts.esd_can_ethercat.gateway import EsdHost, ReadbackError
from gatewaylab.hosts.esd_can_ethercat.handshake import Handshake, RxFrame, RxOverflowError, TxQueueFull

__all__ = ["BitRate", "CanStatus", "EsdConfig", "EsdHost", "EsdQueueApi", "FilterArea", "Handshake", "QueueLayout",
           "ReadbackError", "RxFrame", "RxOverflowError", "TxQueueFull", "api_numerical", "api_register",
           "api_table", "for_bitrate"]
