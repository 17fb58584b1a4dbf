"""Rig files and the runtime that runs them: buses, participants, the real-time loop, faults,
endpoints, the ``[ethercat]`` segment, bridges, tunnels, RigProcess and the pytest plugin. The device
plugin interface is :mod:`gatewaylab.plugin`, the command line :mod:`gatewaylab.cli`.

``from gatewaylab.rig import Rig, load_rig, parse_rig`` (imported on first use, so the command
line starts without loading every device, and a device module that imports
:mod:`gatewaylab.plugin` does not pull the runtime in).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from gatewaylab.rig.config import load_rig, parse_rig
    from gatewaylab.rig.runtime import Rig

__all__ = ["Rig", "load_rig", "parse_rig"]


def __getattr__(name: str) -> Any:
    if name == "Rig":
        from gatewaylab.rig.runtime import Rig

        return Rig
    if name in ("load_rig", "parse_rig"):
        from gatewaylab.rig import config

        return getattr(config, name)
    raise AttributeError(f"module 'gatewaylab.rig' has no attribute {name!r}")
