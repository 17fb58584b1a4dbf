"""Rig-file kind ``drive``: ``[[drive]]`` sections (docs/architecture.md "The rig").

```toml
[[drive]]
bus = "can0"
node_id = 2          # omit: unconfigured (LSS node-ID 0xFF) until an LSS master assigns one
serial = 0x1002      # 0x1018:04, the LSS serial number
name = "axis2"       # optional
plant = { inertia = 4e-5, kp = 80.0 }   # optional: motion plant parameters (AxisParams)
```

Registered as the ``drive`` entry point of ``gatewaylab.devices`` (also ``[[device]] kind = "drive"``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.canopen_drive.plant import AxisParams
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext, state_file

__all__ = ["KEYS", "KIND", "PLANT_KEYS", "axis_params", "create_drive", "default_name"]


_P = AxisParams()
#: The motion plant's parameters (``plant = {...}``), shared by every kind that carries a drive
#: (``[[drive]]``, ``ethercat_drive``); defaults are :class:`AxisParams`'.
PLANT_KEYS: dict[str, Key] = {
    "inertia": Key(float, _P.inertia, min=1e-9, help="kg m^2"),
    "rated_torque": Key(float, _P.rated_torque, min=1e-6, help="Nm, 0x6076"),
    "viscous_friction": Key(float, _P.viscous_friction, min=0, help="Nm s/rad"),
    "coulomb_friction": Key(float, _P.coulomb_friction, min=0, help="Nm"),
    "increments_per_rev": Key(int, _P.increments_per_rev, min=1, max=0x7FFFFFFF, help="0x608F"),
    "kp": Key(float, _P.kp, min=0, help="1/s, position loop"),
    "kv": Key(float, _P.kv, min=0, help="1/s, velocity loop"),
    "ki": Key(float, _P.ki, min=0, help="1/s^2, velocity loop integral"),
}


def axis_params(plant: dict[str, Any] | None) -> AxisParams | None:
    """The validated ``plant`` table as :class:`AxisParams` (None: the defaults)."""
    return AxisParams(**plant) if plant else None


KEYS: dict[str, Key] = {
    "bus": Key(str, required=True, bus=True, help="the name of a [[bus]]"),
    "node_id": Key(int, min=1, max=127, help="omit it for an unconfigured drive"),
    "serial": Key(int, required=True, min=0, max=0xFFFFFFFF, hex=True, help="the LSS serial number, 0x1018:04"),
    "name": Key(str),
    "plant": Key(dict, keys=PLANT_KEYS),
    "control_period": Key(float, 0.001, min=0.0001, max=0.1,
                          help="seconds per run of the drive's control loop (position/velocity loops, plant)"),
}


def default_name(cfg: Mapping[str, Any]) -> str:
    """A drive section's name when the rig file gives none: by node-ID, else by serial."""
    node_id, serial = cfg.get("node_id"), cfg.get("serial")
    return f"drive{node_id}" if node_id is not None else f"drive-{serial:x}"


def create_drive(rig: RigContext, cfg: dict[str, Any]) -> Drive:
    """Build a :class:`Drive` on ``rig.buses[cfg["bus"]]``; stored parameters go to ``rig.state_dir``."""
    cfg = KIND.validate(cfg, "[[drive]]", list(rig.buses))
    name = KIND.name_of(cfg) or default_name(cfg)
    store_path = state_file(rig.state_dir, name, ".params.json")
    drive = Drive(rig.clock, rig.buses[cfg["bus"]], cfg["node_id"], cfg["serial"], name=name, store_path=store_path,
                  params=axis_params(cfg["plant"]))
    drive.period = cfg["control_period"]
    # the ready file lists each drive with its EDS, so `gatewaylab monitor` decodes its PDOs
    eds = state_file(rig.state_dir, name, ".eds")
    eds.write_text(drive.node.to_eds())
    drive.ready_extra = {"canopen": {cfg["bus"]: {name: {"node_id": cfg["node_id"], "serial": cfg["serial"],
                                                         "eds": str(eds)}}}}
    return drive


KIND = DeviceKind("drive", create_drive, KEYS, summary="a maxon IDX-like CiA 402 servo drive on a CAN bus",
                  table="drive", canopen=True, default_name=default_name)
