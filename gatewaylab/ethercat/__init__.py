"""EtherCAT slave core: emulated ESC, mailbox CoE/FoE, raw-socket wire, ESI export.

See docs/ethercat.md. The commonly used names are re-exported here. The in-process master moved to
:mod:`gatewaylab.hosts.ethercat.master`; ``gatewaylab.ethercat.Master`` still finds it for one release.
"""

import importlib
import warnings
from typing import Any

from gatewaylab.ethercat.description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from gatewaylab.ethercat.esc import AlState, Esc
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave, SlaveApplication

__all__ = ["AlState", "DeviceDescription", "Esc", "ObjectDef", "Pdo", "PdoEntry", "Segment", "Slave",
           "SlaveApplication"]


def __getattr__(name: str) -> Any:
    """The old public name ``gatewaylab.ethercat.Master`` (deprecated: a master is not the slave core)."""
    if name == "Master":
        warnings.warn("gatewaylab.ethercat.Master moved to gatewaylab.hosts.ethercat.master.Master",
                      DeprecationWarning, stacklevel=2)
        return importlib.import_module("gatewaylab.hosts.ethercat.master").Master
    raise AttributeError(name)
