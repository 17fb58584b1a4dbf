"""CANopen node stack (CiA 301): object dictionary, NMT, SDO server/client, PDO, SYNC, EMCY,
heartbeat, store/restore; see docs/canopen.md."""

from ..od import Access, DataType, Entry, ObjectCode, ObjectDictionary
from .errors import SdoAbort
from .nmt import NmtCommand, NmtMaster, NmtState
from .node import Node
from .sdo_client import SdoClient

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
