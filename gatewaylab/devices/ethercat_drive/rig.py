"""``[[device]] kind = "ethercat_drive"``: the CoE CiA 402 drive in the rig's ``[ethercat]`` segment.

```toml
[[device]]
kind = "ethercat_drive"
name = "axis1"        # optional
serial = 0x3001       # optional, 0x1018:04
axes = 2              # optional, 1..4 (ETG.6010: axis n at index + 0x800 n)
plant = { kp = 80.0 } # optional, the [[drive]] plant keys
```

The drive joins the segment in rig-file order and is listed in the ready file's
``ethercat.slaves``.
"""

from __future__ import annotations

from typing import Any

from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.canopen_drive.rig import PLANT_KEYS, axis_params
from gatewaylab.devices.ethercat_drive.device import MAX_AXES, EthercatDrive
from gatewaylab.ethercat.slave import Slave
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext

__all__ = ["KEYS", "KIND", "DriveParticipant", "create_drive_device"]


KEYS: dict[str, Key] = {
    "name": Key(str, "ethercat_drive"),
    "serial": Key(int, 0, min=0, max=0xFFFFFFFF, hex=True, help="the identity object's serial number"),
    "axes": Key(int, 1, min=1, max=MAX_AXES, help="ETG.6010 axes, 0x800 apart"),
    "plant": Key(dict, keys=PLANT_KEYS),
}


class DriveParticipant:
    """The rig participant: an :class:`EthercatDrive` whose slave joins the ``[ethercat]`` segment."""

    is_ethercat = True

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        cfg = KIND.validate(cfg, f"[[device]] {cfg.get('name', 'ethercat_drive')}")
        self.name: str = cfg["name"]
        self.device = EthercatDrive(rig.clock, self.name, cfg["serial"], cfg["axes"], axis_params(cfg["plant"]))
        self.slave: Slave = self.device.slave

    @property
    def drive(self) -> Drive:
        """Axis 0's drive (capability HasDrive: what `gatewaylab fault drive-fault NAME` acts on)."""
        return self.device.drive

    def start(self) -> None:
        """Nothing to open: the segment owns the wire; the axes run from construction."""

    def stop(self) -> None:
        """Stop the control periods."""
        self.device.stop()

    def ready_info(self) -> dict[str, Any]:
        """An EtherCAT drive publishes no endpoints of its own (its segment does)."""
        return {}


def create_drive_device(rig: RigContext, cfg: dict[str, Any]) -> DriveParticipant:
    """The rig kind's factory: one EtherCAT drive from its checked section."""
    return DriveParticipant(rig, cfg)


KIND = DeviceKind("ethercat_drive", create_drive_device, KEYS,
                  summary="a CoE CiA 402 servo drive (1..4 axes) in the [ethercat] segment")
