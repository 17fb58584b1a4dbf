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

from ...common.errors import ConfigError
from .device import IdxDevice
from .transport.pty import PtyPort
from .transport.tcp import TcpServer

_KEYS = {"kind", "name", "bus", "node_id", "serial", "usb", "sdo_timeout", "segment_size", "store"}
_USB_KEYS = {"pty", "tcp_port", "latency_ms"}


class IdxParticipant:
    """The rig participant: the device plus its USB transports."""

    def __init__(self, rig: Any, cfg: dict[str, Any]) -> None:
        unknown = set(cfg) - _KEYS
        if unknown:
            raise ConfigError(f"maxon_idx: unknown keys {sorted(unknown)} (known: {sorted(_KEYS)})")
        self.rig = rig
        self.name: str = str(cfg.get("name", "idx"))
        node_id = cfg.get("node_id")
        usb = dict(cfg.get("usb", {"pty": True}))
        unknown = set(usb) - _USB_KEYS
        if unknown:
            raise ConfigError(f"maxon_idx {self.name}: unknown usb keys {sorted(unknown)}")
        self.want_pty = bool(usb.get("pty", True))
        tcp = usb.get("tcp_port")
        if tcp is not None and tcp is not False and (isinstance(tcp, bool) or not isinstance(tcp, int)
                                                      or not 0 <= tcp <= 65535):
            raise ConfigError(f"maxon_idx {self.name}: usb.tcp_port must be 0..65535 (0 = a free port), "
                              f"got {tcp!r}")
        self.tcp_port: int | None = None if tcp is None or tcp is False else int(tcp)
        latency = usb.get("latency_ms", 0.0)
        if isinstance(latency, bool) or not isinstance(latency, int | float) or latency < 0:
            raise ConfigError(f"maxon_idx {self.name}: usb.latency_ms must be a number >= 0, got {latency!r}")
        self.latency = float(latency) / 1000.0
        store = rig.state_dir / f"{self.name}.store" if cfg.get("store", False) else None
        self.device = IdxDevice(rig.clock, rig.bus(str(cfg.get("bus", "can0"))),
                                None if node_id is None else int(node_id), int(cfg.get("serial", 0x2001)),
                                self.name, store_path=store, sdo_timeout=float(cfg.get("sdo_timeout", 0.5)),
                                segment_size=int(cfg.get("segment_size", 255)))
        self.pty: PtyPort | None = None
        self.tcp: TcpServer | None = None

    def start(self) -> None:
        self.device.start()
        if self.want_pty and self.pty is None:
            self.pty = PtyPort(self.rig, self.rig.clock, self.device.open_channel, self.latency)
        if self.tcp_port is not None and self.tcp is None:
            self.tcp = TcpServer(self.rig, self.rig.clock, self.device.open_channel, self.tcp_port,
                                 latency=self.latency)

    def stop(self) -> None:
        if self.pty is not None:
            self.pty.close()
            self.pty = None
        if self.tcp is not None:
            self.tcp.close()
            self.tcp = None
        self.device.stop()

    def ready_info(self) -> dict[str, Any]:
        entry: dict[str, Any] = {}
        if self.pty is not None:
            entry["pty"] = self.pty.path
        if self.tcp is not None:
            entry["tcp"] = self.tcp.address
        return {"usb": {self.name: entry}}


def create_device(rig: Any, cfg: dict[str, Any]) -> IdxParticipant:
    return IdxParticipant(rig, cfg)
