"""EtherCAT slave core: emulated ESC, mailbox CoE/FoE, in-process master, raw-socket wire, ESI export.

See docs/ethercat.md. The commonly used names are re-exported here.
"""

from .description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from .esc import AlState, Esc
from .master import Master
from .segment import Segment
from .slave import Slave, SlaveApplication

__all__ = ["AlState", "DeviceDescription", "Esc", "Master", "ObjectDef", "Pdo", "PdoEntry", "Segment", "Slave",
           "SlaveApplication"]
