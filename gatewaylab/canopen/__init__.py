"""CANopen node stack (CiA 301) on a virtual bus: the node, NMT, SDO server and client, PDO, SYNC,
EMCY, heartbeat and guarding, store/restore, LSS, the CiA 402 state table and the bus monitor; see
docs/canopen.md. A node keeps its objects in the object dictionary of :mod:`gatewaylab.od` (types,
rows, SDO aborts live there)."""

from gatewaylab.canopen.nmt import NmtCommand, NmtMaster, NmtState
from gatewaylab.canopen.node import Node
from gatewaylab.canopen.sdo_client import SdoClient

__all__ = ["NmtCommand", "NmtMaster", "NmtState", "Node", "SdoClient"]
