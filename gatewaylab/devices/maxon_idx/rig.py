"""``[[device]] kind = "maxon_idx"``: an IDX on a rig bus with its USB port as a pty and/or TCP.

```toml
[[device]]
kind = "maxon_idx"
name = "idx1"
bus = "can0"
node_id = 1
serial = 0x2001
usb = { pty = true, tcp_port = 0, latency_ms = 0 }   # tcp_port 0 = pick a free port
```
"""

from __future__ import annotations

from typing import Any

from gatewaylab.canopen.node import Node
from gatewaylab.common.endpoint import format_tcp
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.maxon_idx.commands import MAX_SEGMENT
from gatewaylab.devices.maxon_idx.device import IdxDevice
from gatewaylab.devices.maxon_idx.transport.pty import PtyPort
from gatewaylab.devices.maxon_idx.transport.tcp import TcpServer
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext, state_file

__all__ = ["KEYS", "KIND", "USB_KEYS", "IdxParticipant", "create_device"]


USB_KEYS: dict[str, Key] = {
    "pty": Key(bool, True),
    "tcp_port": Key(int, min=0, max=65535, false_is_none=True, help="0 = a free port"),
    "latency_ms": Key(float, 0.0, min=0),
}
KEYS: dict[str, Key] = {
    "name": Key(str, "idx"),
    "bus": Key(str, "can0", bus=True),
    "node_id": Key(int, min=1, max=127, help="omit it for an unconfigured IDX"),
    "serial": Key(int, 0x2001, min=0, max=0xFFFFFFFF, hex=True, help="the LSS serial number"),
    "usb": Key(dict, keys=USB_KEYS),
    "sdo_timeout": Key(float, 0.5, min=0.001, help="seconds"),
    "segment_size": Key(int, MAX_SEGMENT, min=1, max=MAX_SEGMENT),
    "store": Key(bool, False),
}


class IdxParticipant:
    """The rig participant: the device plus its USB transports."""

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        cfg = KIND.validate(cfg, f"maxon_idx {cfg.get('name', 'idx')}", list(rig.buses))
        self.rig = rig
        self.name: str = cfg["name"]
        usb = cfg["usb"]
        self.want_pty: bool = usb["pty"]
        self.tcp_port: int | None = usb["tcp_port"]
        self.latency = usb["latency_ms"] / 1000.0
        store = state_file(rig.state_dir, self.name, ".store") if cfg["store"] else None
        self.device = IdxDevice(rig.clock, rig.bus(cfg["bus"]), cfg["node_id"], cfg["serial"], self.name,
                                store_path=store, sdo_timeout=cfg["sdo_timeout"], segment_size=cfg["segment_size"])
        self.bus_name: str = cfg["bus"]
        self.serial: int = cfg["serial"]
        # the IDX is a CANopen node on its bus like a drive: the ready file lists it with its EDS, so
        # `gatewaylab monitor` shows it in the node table and decodes its PDOs
        self.eds = rig.state_dir / f"{self.name}.eds"
        self.eds.write_text(self.device.node.to_eds())
        self.pty: PtyPort | None = None
        self.tcp: TcpServer | None = None
        self.unplugged = False

    @property
    def node(self) -> Node:
        """The IDX's CANopen node (capability HasNode: fault injection finds it by node-ID)."""
        return self.device.node

    @property
    def drive(self) -> Drive:
        """The drive inside the IDX (capability HasDrive: power cycle and drive faults)."""
        return self.device.drive

    def start(self) -> None:
        """Start the device and open its USB side (virtual serial port and/or TCP port)."""
        self.device.start()
        self._open_usb()

    def _open_usb(self) -> None:
        if self.unplugged:
            return
        if self.want_pty and self.pty is None:
            self.pty = PtyPort(self.rig, self.rig.clock, self.device.open_channel, self.latency)
        if self.tcp_port is not None and self.tcp is None:
            self.tcp = TcpServer(self.rig, self.rig.clock, self.device.open_channel, self.tcp_port,
                                 latency=self.latency)

    def usb_unplug(self) -> None:
        """Fault injection (docs/faults.md): the USB cable is pulled. The host's open port fails
        (a pty hangs up, TCP connections close) and the port refuses hosts until replugged."""
        self.unplugged = True
        if self.pty is not None:
            self.pty.close()
            self.pty = None
        if self.tcp is not None:
            self.tcp_port = self.tcp.port      # the same port comes back at replug
            self.tcp.close()
            self.tcp = None

    def usb_replug(self) -> None:
        """The cable is back: the port enumerates again (a new pty path, the same TCP port)."""
        if self.unplugged:
            self.unplugged = False
            self._open_usb()

    def stop(self) -> None:
        """Close the USB side, then stop the device."""
        if self.pty is not None:
            self.pty.close()
            self.pty = None
        if self.tcp is not None:
            self.tcp.close()
            self.tcp = None
        self.device.stop()

    def ready_info(self) -> dict[str, Any]:
        """Where hosts reach this IDX (pty path, TCP address) and its CANopen node (node-ID, serial, EDS),
        for the ready file."""
        entry: dict[str, Any] = {}
        if self.pty is not None:
            entry["pty"] = self.pty.path
        if self.tcp is not None:
            entry["tcp"] = format_tcp(self.tcp.host, self.tcp.port)   # docs/endpoints.md
        node = {"node_id": self.device.node.node_id, "serial": self.serial, "eds": str(self.eds)}
        return {"usb": {self.name: entry}, "canopen": {self.bus_name: {self.name: node}}}


def create_device(rig: RigContext, cfg: dict[str, Any]) -> IdxParticipant:
    """The rig kind's factory: one IDX from its checked section."""
    return IdxParticipant(rig, cfg)


KIND = DeviceKind("maxon_idx", create_device, KEYS, summary="maxon IDX: USB command protocol and SDO gateway",
                  canopen=True)
