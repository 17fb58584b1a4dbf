"""CANopen node stack (CiA 301): object dictionary, NMT, SDO server/client, PDO, SYNC, EMCY,
heartbeat, store/restore; see docs/canopen.md."""

from gatewaylab.canopen.errors import SdoAbort
from gatewaylab.canopen.nmt import NmtCommand, NmtMaster, NmtState
from gatewaylab.canopen.node import Node
from gatewaylab.canopen.sdo_client import SdoClient
from gatewaylab.od import Access, DataType, Entry, ObjectCode, ObjectDictionary

__all__ = [
    "Access",
    "DataType",
    "Entry",
    "NmtCommand",
    "NmtMaster",
    "NmtState",
    "Node",
    "ObjectCode",
    "ObjectDictionary",
    "SdoAbort",
    "SdoClient",
]
