"""Helpers of the ECAN-Lite host-library tests: a rig file with ECAN-Lites and CiA 402 drives on a
simulated clock (``gatewaylab.hosts.ecanlite.demo.rig_toml``), the in-process backend on it,
and the three layers built the way 15.5.2 / 15.5.4 describe."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.hosts.ecanlite.adapter import AdapterConfig, EcanAdapter
from gatewaylab.hosts.ecanlite.demo import rig_toml
from gatewaylab.hosts.ecanlite.port import ChannelConfig, McanPort, PortConfig
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.rig.runtime import Rig


@dataclass
class HostRig:
    rig: Rig
    backend: InProcessBackend
    path: Path


@contextlib.contextmanager
def host_rig(tmp_path: Path, drives: Sequence[Sequence[int]] = ((1,),), **kwargs: object) -> Iterator[HostRig]:
    """The rig of ``rig_toml(drives)`` started on a simulated clock with a backend in PREOP."""
    path = tmp_path / "rig.toml"
    path.write_text(rig_toml(drives, **kwargs))  # type: ignore[arg-type]
    rig = Rig.from_file(str(path), clock=SimulatedClock(), endpoints=False)
    try:
        rig.start()
        yield HostRig(rig, InProcessBackend.from_rig(rig), path)
    finally:
        rig.close()


def classic_port(backend: InProcessBackend, channels: Sequence[int] = (0, 1, 2, 3), multiplier: int = 3,
                 **port_kwargs: object) -> tuple[EcanAdapter, McanPort]:
    """Adapter (slave 0, N = ``multiplier``) and Port with classic 1 Mbit/s channels, started (OP)."""
    adapter = EcanAdapter(backend, AdapterConfig.for_positions([0], multiplier,
                                                               dc_sync0=bool(port_kwargs.pop("dc_sync0", False))))
    port = McanPort(adapter, PortConfig({ch: ChannelConfig.classic() for ch in channels}, **port_kwargs))  # type: ignore[arg-type]
    adapter.start()
    return adapter, port
