"""python-can interfaces over the EtherCAT gateways, one channel each (entry points ``can.interface``).

``can.Bus(interface="ecanlite", channel=LINE, slave=0, can_channel=0, bitrate=1_000_000,
data_bitrate=None, fd=False, cycle_us=1000, pdo_n=3)``

``can.Bus(interface="esd_can_ethercat", channel=LINE, slave=0, bitrate=500_000, cycle_us=1000)``

LINE is a network interface (``eth1``: SOEM through pysoem, root) or ``rig:PATH.toml``: the rig of
that file runs in this process on a simulated clock (no root, no network; the clock advances
while ``send()`` waits for the frame and its answers, see :mod:`.host`). The gateway is
configured at start-up from the arguments; ``shutdown()`` brings it back to PREOP.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import can

from ...common.clock import SimulatedClock
from ...common.errors import GatewaylabError
from ...ethercat.backend import InProcessBackend, MasterBackend
from .host import EthercatHost, GatewayBus

RIG_PREFIX = "rig:"


def open_line(channel: Any, timeout: float = 0.1) -> tuple[MasterBackend, Callable[[], None] | None, float]:
    """(backend, closer of what was opened for it, wall epoch) for ``channel``."""
    if not isinstance(channel, str) or not channel:
        raise can.CanInitializationError("channel must name a network interface or rig:PATH.toml")
    if channel.startswith(RIG_PREFIX):
        from ...rig.runtime import Rig  # the rig layer only when a rig is asked for

        rig = Rig.from_file(channel[len(RIG_PREFIX):], clock=SimulatedClock(), endpoints=False)
        try:
            rig.start()
            return InProcessBackend.from_rig(rig, timeout=timeout), rig.close, 0.0
        except BaseException:
            rig.close()
            raise
    from ...ethercat.backend import PysoemBackend

    return PysoemBackend(channel), None, 0.0


def _host(channel: Any, cycle_us: int) -> EthercatHost:
    try:
        backend, closer, epoch = open_line(channel)
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


class EsdCanEthercatBus(GatewayBus):
    """``can.Bus(interface="esd_can_ethercat", channel=LINE, slave=0, bitrate=500_000, cycle_us=1000)``."""

    def __init__(self, channel: Any, slave: int = 0, bitrate: int = 500_000, cycle_us: int = 1000,
                 **kwargs: Any) -> None:
        host = _host(channel, cycle_us)
        try:
            ch = host.add_esd(int(slave), int(bitrate), name=str(channel))
        except BaseException:
            host.close()
            raise
        _start(host)
        GatewayBus.__init__(self, host, ch.name, owns_host=True, **kwargs)


class EcanliteBus(GatewayBus):
    """``can.Bus(interface="ecanlite", channel=LINE, slave=0, can_channel=0, bitrate=1_000_000,
    data_bitrate=None, fd=False, cycle_us=1000, pdo_n=3)``: one MCAN channel of an ECAN-Lite."""

    def __init__(self, channel: Any, slave: int = 0, can_channel: int = 0, bitrate: int = 1_000_000,
                 data_bitrate: int | None = None, fd: bool = False, cycle_us: int = 1000, pdo_n: int = 3,
                 **kwargs: Any) -> None:
        host = _host(channel, cycle_us)
        try:
            ch = host.add_ecanlite(int(slave), int(can_channel), int(bitrate),
                                   int(data_bitrate) if data_bitrate else None, bool(fd), int(pdo_n),
                                   name=str(channel))
        except GatewaylabError as exc:
            host.close()
            raise can.CanInitializationError(str(exc)) from exc
        _start(host)
        GatewayBus.__init__(self, host, ch.name, owns_host=True, **kwargs)
