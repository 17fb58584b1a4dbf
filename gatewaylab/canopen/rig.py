"""Rig-file kind ``drive``: ``[[drive]]`` sections (docs/architecture.md "The rig").

```toml
[[drive]]
bus = "can0"
node_id = 2          # omit: unconfigured (LSS node-ID 0xFF) until an LSS master assigns one
serial = 0x1002      # 0x1018:04, the LSS serial number
name = "axis2"       # optional
```

Registered as the ``drive`` entry point of ``gatewaylab.devices`` (also ``[[device]] kind = "drive"``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..bus.participant import DeviceKind, Key, RigContext
from .drive import Drive

KEYS: dict[str, Key] = {
    "bus": Key(str, required=True, bus=True, help="the name of a [[bus]]"),
    "node_id": Key(int, min=1, max=127, help="omit it for an unconfigured drive"),
    "serial": Key(int, required=True, min=0, max=0xFFFFFFFF, hex=True, help="the LSS serial number, 0x1018:04"),
    "name": Key(str),
}


def default_name(cfg: Mapping[str, Any]) -> str:
    node_id, serial = cfg.get("node_id"), cfg.get("serial")
    return f"drive{node_id}" if node_id is not None else f"drive-{serial:x}"


def create_drive(rig: RigContext, cfg: dict[str, Any]) -> Drive:
    """Build a :class:`Drive` on ``rig.buses[cfg["bus"]]``; stored parameters go to ``rig.state_dir``."""
    cfg = KIND.validate(cfg, "[[drive]]", list(rig.buses))
    name = KIND.name_of(cfg) or default_name(cfg)
    store_path = rig.state_dir / f"{name}.params.json"
    drive = Drive(rig.clock, rig.buses[cfg["bus"]], cfg["node_id"], cfg["serial"], name=name, store_path=store_path)
    # the ready file lists each drive with its EDS, so `gatewaylab monitor` decodes its PDOs
    eds = rig.state_dir / f"{name}.eds"
    eds.write_text(drive.node.to_eds())
    drive.ready_extra = {"canopen": {cfg["bus"]: {name: {"node_id": cfg["node_id"], "serial": cfg["serial"],
                                                         "eds": str(eds)}}}}
    return drive


KIND = DeviceKind("drive", create_drive, KEYS, summary="a maxon IDX-like CiA 402 servo drive on a CAN bus",
                  table="drive", canopen=True, default_name=default_name)
