"""EtherCAT slave core: emulated ESC, mailbox CoE/FoE, raw-socket wire, ESI export.

See docs/ethercat.md. The commonly used names are re-exported here. The master side (the in-process
:class:`~gatewaylab.hosts.ethercat.master.Master` and the backends) lives in :mod:`gatewaylab.hosts.ethercat`.
"""

from gatewaylab.ethercat.description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from gatewaylab.ethercat.esc import AlState, Esc
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave, SlaveApplication

__all__ = ["AlState", "DeviceDescription", "Esc", "ObjectDef", "Pdo", "PdoEntry", "Segment", "Slave",
           "SlaveApplication"]

