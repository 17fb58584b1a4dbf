"""python-can interfaces over the EtherCAT gateways, one channel each (entry points ``can.interface``).

``can.Bus(interface="ecanlite", channel=LINE, slave=0, can_channel=0, bitrate=1_000_000,
data_bitrate=None, fd=False, cycle_us=1000, pdo_n=3)``

``can.Bus(interface="esd_can_ethercat", channel=LINE, slave=0, bitrate=500_000, cycle_us=1000)``

LINE is a network interface (``eth1``: SOEM through pysoem, root) or ``rig:PATH.toml``: the rig of
that file runs in this process on a simulated clock (no root, no network; the clock advances
while ``send()`` waits for the frame and its answers, see :mod:`.host`). The rig form comes with
the classes of ``gatewaylab.rig.canhost`` (the ones the entry points name). The gateway is
configured at start-up from the arguments; ``shutdown()`` brings it back to PREOP.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import can

from gatewaylab.common.errors import GatewaylabError
from gatewaylab.hosts.canhost.host import EthercatHost, GatewayBus
from gatewaylab.hosts.ethercat.backend import MasterBackend

__all__ = ["RIG_PREFIX", "EcanliteBus", "EsdCanEthercatBus", "RigOpener", "open_line"]


RIG_PREFIX = "rig:"


#: Opens ``rig:PATH`` lines: (backend, closer, wall epoch). The rig layer supplies it
#: (``gatewaylab.rig.canhost``, whose classes the entry points name): devices never import rig.
RigOpener = Callable[[str], tuple[MasterBackend, Callable[[], None] | None, float]]


def open_line(channel: Any, open_rig: RigOpener | None = None,
              pd_timeout_us: int = 20_000) -> tuple[MasterBackend, Callable[[], None] | None, float]:
    """(backend, closer of what was opened for it, wall epoch) for ``channel``; ``pd_timeout_us``:
    how long SOEM waits for the process data frame to come back."""
    if not isinstance(channel, str) or not channel:
        raise can.CanInitializationError("channel must name a network interface or rig:PATH.toml")
    if channel.startswith(RIG_PREFIX):
        if open_rig is None:
            raise can.CanInitializationError(f"{channel}: rig lines need gatewaylab.rig.canhost's interfaces")
        return open_rig(channel[len(RIG_PREFIX):])
    from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend

    return PysoemBackend(channel, pd_timeout_us=pd_timeout_us), None, 0.0


def _host(channel: Any, cycle_us: int, open_rig: RigOpener | None, pd_timeout_us: int) -> EthercatHost:
    try:
        backend, closer, epoch = open_line(channel, open_rig, pd_timeout_us)
    except GatewaylabError as exc:
        raise can.CanInitializationError(f"{channel}: {exc}") from exc
    return EthercatHost(backend, cycle_us=cycle_us, owned=closer, wall_epoch=epoch)


def _start(host: EthercatHost) -> None:
    try:
        host.start()
    except GatewaylabError as exc:
        host.close()
        raise can.CanInitializationError(str(exc)) from exc
    except BaseException:
        host.close()
        raise


class _LineBus(GatewayBus):
    """A plugin bus that opens its own line (and owns its host)."""

    #: how ``rig:PATH`` lines open; None here (the rig layer's subclasses give one)
    open_rig: RigOpener | None = None


class EsdCanEthercatBus(_LineBus):
    """``can.Bus(interface="esd_can_ethercat", channel=LINE, slave=0, bitrate=500_000, cycle_us=1000)``."""

    def __init__(self, channel: Any, slave: int = 0, bitrate: int = 500_000, cycle_us: int = 1000,
                 pd_timeout_us: int = 20_000, **kwargs: Any) -> None:
        host = _host(channel, cycle_us, self.open_rig, int(pd_timeout_us))
        try:
            ch = host.add_esd(int(slave), int(bitrate), name=str(channel))
        except BaseException:
            host.close()
            raise
        _start(host)
        GatewayBus.__init__(self, host, ch.name, owns_host=True, **kwargs)


class EcanliteBus(_LineBus):
    """``can.Bus(interface="ecanlite", channel=LINE, slave=0, can_channel=0, bitrate=1_000_000,
    data_bitrate=None, fd=False, cycle_us=1000, pdo_n=3)``: one MCAN channel of an ECAN-Lite."""

    def __init__(self, channel: Any, slave: int = 0, can_channel: int = 0, bitrate: int = 1_000_000,
                 data_bitrate: int | None = None, fd: bool = False, cycle_us: int = 1000, pdo_n: int = 3,
                 pd_timeout_us: int = 20_000, **kwargs: Any) -> None:
        host = _host(channel, cycle_us, self.open_rig, int(pd_timeout_us))
        try:
            ch = host.add_ecanlite(int(slave), int(can_channel), int(bitrate),
                                   int(data_bitrate) if data_bitrate else None, bool(fd), int(pdo_n),
                                   name=str(channel))
        except GatewaylabError as exc:
            host.close()
            raise can.CanInitializationError(str(exc)) from exc
        _start(host)
        GatewayBus.__init__(self, host, ch.name, owns_host=True, **kwargs)
