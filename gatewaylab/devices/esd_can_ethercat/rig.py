"""``[[device]] kind = "esd_can_ethercat"``: the esd CAN-EtherCAT gateway in a rig.

```toml
[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"
web_port = 0          # optional: the web interface of chapter 6 on 127.0.0.1 (0 = any free port)
serial = 0x1234       # optional: 0x1018:04
update_seconds = 3.0  # optional: how long a firmware update takes on the clock
```

The gateway joins the ``[ethercat]`` segment (listed in the ready file's ``ethercat.slaves``); with
``web_port`` its base URL appears in the ready file as ``"web": {"esd1": "http://127.0.0.1:PORT/"}``.
"""

from __future__ import annotations

from typing import Any

from gatewaylab.devices.esd_can_ethercat.device import EsdGateway
from gatewaylab.devices.esd_can_ethercat.webmodel import EsdWebModel
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext

__all__ = ["KEYS", "KIND", "EsdParticipant", "create"]


KEYS: dict[str, Key] = {
    "name": Key(str, "esd"),
    "bus": Key(str, "can0", bus=True, help="the name of a [[bus]]"),
    "web_port": Key(int, min=0, max=65535, false_is_none=True, help="0 = any free port on 127.0.0.1"),
    "serial": Key(int, 0, min=0, max=0xFFFFFFFF, hex=True, help="the identity object's serial number"),
    "update_seconds": Key(float, 3.0, min=0, max=600, help="seconds a firmware update takes"),
}


class EsdParticipant:
    """The rig participant: the gateway (an EtherCAT device of the segment) and its web server."""

    is_ethercat = True

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        cfg = KIND.validate(cfg, f"[[device]] {cfg.get('name', 'esd')}", list(rig.buses))
        self.rig = rig
        self.name: str = cfg["name"]
        self.web_port: int | None = cfg["web_port"]
        self.gateway = EsdGateway(rig.clock, rig.bus(cfg["bus"]), self.name, cfg["serial"], cfg["update_seconds"])
        self.slave = self.gateway.slave
        self.web: Any = None
        self.url: str | None = None

    def start(self) -> None:
        """Attach to the bus, then start the web server (a failed start leaves nothing running)."""
        self.gateway.start()
        if self.web_port is not None and self.web is None:
            from gatewaylab.devices.esd_can_ethercat.web import EsdWebServer

            server = EsdWebServer(EsdWebModel(self.gateway), self.rig.clock.lock, port=self.web_port)
            try:
                self.url = server.start()
            except BaseException:
                server.stop()
                self.gateway.stop()
                raise
            self.web = server

    def stop(self) -> None:
        """Stop the web server and leave the bus."""
        if self.web is not None:
            self.web.stop()
            self.web = None
            self.url = None
        self.gateway.stop()

    def can_channels(self) -> dict[str, Any]:
        """The gateway's CAN controller once attached, for fault injection (docs/faults.md)."""
        ctrl = self.gateway.controller
        return {"can": ctrl} if ctrl is not None else {}

    def ready_info(self) -> dict[str, Any]:
        """The web interface's URL for the ready file, when the rig serves it."""
        return {"web": {self.name: self.url}} if self.url else {}


def create(rig: RigContext, cfg: dict[str, Any]) -> EsdParticipant:
    """The rig kind's factory: one gateway from its checked section."""
    return EsdParticipant(rig, cfg)


KIND = DeviceKind("esd_can_ethercat", create, KEYS,
                  summary="the esd CAN-EtherCAT gateway (EtherCAT slave, MDP 5000 CAN queues, web interface)")
