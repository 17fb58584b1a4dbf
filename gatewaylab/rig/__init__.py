"""Rig files, the runtime that runs them, the device plugin interface and the `gatewaylab` command line.

``from gatewaylab.rig import Rig`` is the runtime (imported on first use, so a device module that
imports :mod:`gatewaylab.rig.plugin` does not pull the runtime in).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .runtime import Rig

__all__ = ["Rig"]


def __getattr__(name: str) -> Any:
    if name == "Rig":
        from .runtime import Rig

        return Rig
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
