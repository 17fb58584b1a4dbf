"""``[[device]] kind = "modbus_gateway"``: a Modbus TCP server that maps CANopen objects to registers.

```toml
[[device]]
kind = "modbus_gateway"
name = "modbus1"
bus = "can0"
node_id = 100        # the gateway's own node id on the bus (its SDO client)
tcp_port = 0         # 0 = a free port on 127.0.0.1 (the ready file names it); false = no TCP server
nodes = [2, 3]       # the CANopen nodes it serves; Modbus unit id = node id
# map = [{ register = 10, kind = "input", index = 0x1018, subindex = 4, type = "u32" }]
# sdo_timeout = 0.5  # s; a node silent for longer -> exception 0x0B
```

Without ``map`` the CiA 402 default map applies (docs/devices/modbus_gateway.md).
"""

from __future__ import annotations

from typing import Any

from gatewaylab.common.endpoint import format_tcp
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.modbus_gateway.device import ModbusGateway
from gatewaylab.devices.modbus_gateway.mapping import RegisterMap, default_cia402_map, parse_map
from gatewaylab.devices.modbus_gateway.server import ModbusTcpFace
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext

__all__ = ["KEYS", "KIND", "ModbusGatewayParticipant", "create_device"]


KEYS: dict[str, Key] = {
    "name": Key(str, "modbus"),
    "bus": Key(str, "can0", bus=True, help="the name of a [[bus]]"),
    "node_id": Key(int, required=True, min=1, max=127, help="the gateway's own CANopen node id"),
    "tcp_port": Key(int, 0, min=0, max=65535, false_is_none=True, help="0 = a free port, false = none"),
    "nodes": Key(list, required=True, help="a list of CANopen node ids 1..127, e.g. [2, 3]"),
    "map": Key(list, help="a list of {register, kind, index, subindex, type} tables"),
    "sdo_timeout": Key(float, 0.5, min=0.001, max=60, help="seconds"),
}


def _nodes(value: list[Any], own: int) -> tuple[int, ...]:
    nodes: list[int] = []
    for n in value:
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 127:
            raise ConfigError(f"nodes must be CANopen node ids 1..127, got {n!r}")
        if n in nodes:
            raise ConfigError(f"nodes lists node {n} twice")
        if n == own:
            raise ConfigError(f"nodes lists the gateway's own node_id {n}")
        nodes.append(n)
    if not nodes:
        raise ConfigError("nodes must name at least one CANopen node")
    return tuple(nodes)


class ModbusGatewayParticipant:
    """The rig participant: the gateway core plus (in real time) its Modbus TCP server."""

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        cfg = KIND.validate(cfg, f"modbus_gateway {cfg.get('name', 'modbus')}", list(rig.buses))
        self.rig = rig
        self.name: str = cfg["name"]
        self.node_id: int = cfg["node_id"]
        self.nodes = _nodes(cfg["nodes"], self.node_id)
        rows = parse_map(cfg["map"]) if cfg["map"] is not None else default_cia402_map()
        self.map = RegisterMap(rows)
        self.tcp_port: int | None = cfg["tcp_port"]
        self.gateway = ModbusGateway(rig.clock, rig.bus(cfg["bus"]), self.name, self.nodes, self.map,
                                     sdo_timeout=cfg["sdo_timeout"])
        self.face: ModbusTcpFace | None = None

    def start(self) -> None:
        """Start the gateway and, on a real-time rig with a port, its Modbus TCP server."""
        self.gateway.start()
        # A simulated clock runs only when its owner moves it: no server thread could wait on it.
        if self.rig.realtime and self.tcp_port is not None and self.face is None:
            face = ModbusTcpFace(self.gateway, self.rig.clock, self.tcp_port)
            face.start()             # raises OSError (port in use) after cleaning up its thread
            self.face = face

    def stop(self) -> None:
        """Stop the Modbus TCP server, then the gateway."""
        if self.face is not None:
            self.face.stop()
            self.face = None
        self.gateway.stop()

    def ready_info(self) -> dict[str, Any]:
        """The Modbus TCP address for the ready file, when the server runs."""
        if self.face is None:
            return {}
        return {"modbus": {self.name: format_tcp(self.face.host, self.face.port)}}


def create_device(rig: RigContext, cfg: dict[str, Any]) -> ModbusGatewayParticipant:
    """The rig kind's factory: one Modbus gateway from its checked section."""
    return ModbusGatewayParticipant(rig, cfg)


KIND = DeviceKind("modbus_gateway", create_device, KEYS,
                  summary="Modbus TCP to CANopen gateway: objects of chosen nodes as registers", canopen=True)
