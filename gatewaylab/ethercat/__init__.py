"""EtherCAT slave core: emulated ESC, mailbox CoE/FoE, in-process master, raw-socket wire, ESI export.

See docs/ethercat.md. The commonly used names are re-exported here.
"""

from gatewaylab.ethercat.description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from gatewaylab.ethercat.esc import AlState, Esc
from gatewaylab.ethercat.master import Master
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave, SlaveApplication

__all__ = ["AlState", "DeviceDescription", "Esc", "Master", "ObjectDef", "Pdo", "PdoEntry", "Segment", "Slave",
           "SlaveApplication"]
