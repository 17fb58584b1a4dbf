"""Rig-file factory for ``[[drive]]`` sections (docs/architecture.md "The rig").

```toml
[[drive]]
bus = "can0"
node_id = 2          # omit: unconfigured (LSS node-ID 0xFF) until an LSS master assigns one
serial = 0x1002      # 0x1018:04, the LSS serial number
name = "axis2"       # optional
```
"""

from __future__ import annotations

from typing import Any

from ..common.errors import ConfigError
from .drive import Drive

_KEYS = {"bus", "node_id", "serial", "name"}


def create_drive(rig: Any, cfg: dict[str, Any]) -> Drive:
    """Build a :class:`Drive` on ``rig.buses[cfg["bus"]]``; stored parameters go to ``rig.state_dir``."""
    unknown = set(cfg) - _KEYS
    if unknown:
        raise ConfigError(f"[[drive]]: unknown keys {sorted(unknown)} (known: {sorted(_KEYS)})")
    bus_name = cfg.get("bus")
    if not isinstance(bus_name, str):
        raise ConfigError("[[drive]]: 'bus' (the name of a [[bus]]) is required")
    buses = rig.buses
    if bus_name not in buses:
        raise ConfigError(f"[[drive]]: no bus named {bus_name!r} (buses: {sorted(buses)})")
    serial = cfg.get("serial")
    if not isinstance(serial, int) or isinstance(serial, bool) or not 0 <= serial <= 0xFFFFFFFF:
        raise ConfigError(f"[[drive]]: 'serial' must be an integer 0..0xFFFFFFFF, got {serial!r}")
    node_id = cfg.get("node_id")
    if node_id is not None and (not isinstance(node_id, int) or isinstance(node_id, bool)
                                or not 1 <= node_id <= 127):
        raise ConfigError(f"[[drive]]: 'node_id' must be 1..127 (omit it for an unconfigured drive), "
                          f"got {node_id!r}")
    name = cfg.get("name")
    if name is None:
        name = f"drive{node_id}" if node_id is not None else f"drive-{serial:x}"
    elif not isinstance(name, str) or not name:
        raise ConfigError(f"[[drive]]: 'name' must be a non-empty string, got {name!r}")
    store_path = rig.state_dir / f"{name}.params.json"
    return Drive(rig.clock, buses[bus_name], node_id, serial, name=name, store_path=store_path)
