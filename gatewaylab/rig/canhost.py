"""The python-can interfaces ``ecanlite`` and ``esd_can_ethercat`` with ``channel="rig:PATH.toml"``.

The interfaces live in ``gatewaylab.hosts.canhost.interfaces``; building a rig from a file belongs to
this layer, so these subclasses hand it down (the layering of docs/architecture.md: devices never
import rig). The entry points (group ``can.interface``) name these classes.
"""

from __future__ import annotations

from collections.abc import Callable

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.hosts.canhost import interfaces
from gatewaylab.hosts.ethercat.backend import MasterBackend
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.rig.runtime import Rig


def open_rig(path: str) -> tuple[MasterBackend, Callable[[], None] | None, float]:
    """The rig of ``path`` on a simulated clock, without bus endpoints or wires, started; a master
    on its EtherCAT segment; closing the host closes the rig."""
    rig = Rig.from_file(path, clock=SimulatedClock(), endpoints=False)
    try:
        rig.start()
        return InProcessBackend.from_rig(rig), rig.close, 0.0
    except BaseException:
        rig.close()
        raise


class EcanliteBus(interfaces.EcanliteBus):
    """``can.Bus(interface="ecanlite", ...)``: a network interface or ``rig:PATH.toml``."""

    open_rig = staticmethod(open_rig)


class EsdCanEthercatBus(interfaces.EsdCanEthercatBus):
    """``can.Bus(interface="esd_can_ethercat", ...)``: a network interface or ``rig:PATH.toml``."""

    open_rig = staticmethod(open_rig)
