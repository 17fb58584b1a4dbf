"""Rig-file kind ``canopen_node``: any CANopen device from its EDS or DCF (docs/bring-your-own-network.md).

```toml
[[device]]
kind = "canopen_node"
eds = "sensor.dcf"       # EDS or DCF; relative to the rig file's folder
bus = "can0"
node_id = 5              # optional with a DCF ([DeviceComissioning] NodeID) or LSS_Supported=1
name = "sensor"          # optional
serial = 0x1234          # optional: 0x1018:04 and the LSS serial number
[device.behaviour]
"0x6401:01" = { sine = { amplitude = 1000, period = 2.0 } }
```
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_node.device import CanopenNodeDevice
from gatewaylab.od.eds import read_eds
from gatewaylab.plugin.behaviour import Behaviour, load_hook, parse_behaviour
from gatewaylab.plugin.capabilities import HasNode
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext

__all__ = ["KEYS", "KIND", "create_node", "default_name"]

log = logging.getLogger(__name__)

KEYS: dict[str, Key] = {
    "bus": Key(str, required=True, bus=True, help="the name of a [[bus]]"),
    "eds": Key(str, required=True, help="the EDS or DCF file, relative to the rig file's folder"),
    "node_id": Key(int, min=1, max=127, help="default: the DCF's [DeviceComissioning] NodeID"),
    "name": Key(str),
    "serial": Key(int, min=0, max=0xFFFFFFFF, hex=True, help="0x1018:04, the LSS serial number"),
    "behaviour": Key(dict, help="rules per entry: echo, counter, sine, ramp, value, random"),
    "behaviour_period": Key(float, 0.01, min=0.0005, max=60.0, help="seconds between two evaluations of the rules"),
    "hook": Key(str, help="package.module:function called each behaviour period with (values, t)"),
}


def default_name(cfg: Mapping[str, Any]) -> str:
    """A node's name when the rig file gives none: the file's stem (letters, digits, ``_.-`` kept) and
    the node-ID."""
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(str(cfg.get("eds", "node"))).stem).lstrip(".-") or "node"
    node_id = cfg.get("node_id")
    return f"{stem}-{node_id}" if node_id is not None else stem


def create_node(rig: RigContext, cfg: dict[str, Any]) -> CanopenNodeDevice:
    """Read the EDS/DCF, build the node on ``cfg["bus"]``; stored parameters go to ``rig.state_dir``."""
    cfg = KIND.validate(cfg, "[[device]] canopen_node", list(rig.buses))
    name = KIND.name_of(cfg) or default_name(cfg)
    source = Path(cfg["eds"]).expanduser()
    if not source.is_absolute():
        source = rig.base_dir / source
    try:
        text = source.read_text(encoding="latin-1")
    except OSError as exc:
        raise ConfigError(f"eds = {cfg['eds']!r}: cannot read {source} ({exc.strerror or exc})") from None
    try:
        od, warnings = read_eds(text, cfg["node_id"], parameter_values=source.suffix.lower() == ".dcf")
    except ConfigError as exc:
        raise ConfigError(f"eds = {cfg['eds']!r}: {source.name}: {exc}") from None
    for warning in warnings:
        log.warning("%s: %s: %s", name, source.name, warning)
    node_id = cfg["node_id"] if cfg["node_id"] is not None else od.node_id
    if node_id is not None:
        for other in rig.participants:   # a node-ID the file gave is checked here (the rig file's by the planner)
            if isinstance(other, HasNode) and other.node.bus is rig.bus(cfg["bus"]) and other.node.node_id == node_id:
                raise ConfigError(f"node_id {node_id} (from {source.name if cfg['node_id'] is None else 'node_id'}) "
                                  f"is already used on bus {cfg['bus']!r} by {other.name} (CANopen node-IDs are "
                                  "unique per bus)")
    lss = od.device_info.get("LSS_Supported", "0").strip() not in ("", "0", "false", "False")
    device = CanopenNodeDevice(rig, name, cfg["bus"], node_id, od, source=source, serial=cfg["serial"], lss=lss,
                               store_path=rig.state_dir / f"{name}.params.json",
                               behaviour_period=cfg["behaviour_period"])
    if cfg["behaviour"] or cfg["hook"]:
        # checked against the node's whole dictionary (the communication objects it adds included)
        rules = parse_behaviour(cfg["behaviour"] or {}, device.node.od)
        hook = load_hook(cfg["hook"]) if cfg["hook"] else None
        device.behaviour = Behaviour(rules, device.node.od, hook)
    # the ready file lists the node with its EDS, so `gatewaylab monitor` decodes its PDOs
    eds = rig.state_dir / f"{name}.eds"
    eds.write_text(device.node.to_eds())
    device.ready_extra = {"canopen": {cfg["bus"]: {name: {
        "node_id": node_id, "serial": device.node.get(0x1018, 4) if (0x1018, 4) in od.entries else None,
        "eds": str(eds), "source": str(source)}}}}
    return device


KIND = DeviceKind("canopen_node", create_node, KEYS, summary="any CANopen device from its EDS or DCF",
                  canopen=True, default_name=default_name)
