"""``[[device]] kind = "ecanlite"``: an ECAN-Lite on the rig's EtherCAT segment and CAN buses.

Rig file::

    [[device]]
    kind = "ecanlite"
    name = "ecan"                   # optional
    channels = ["can0", "can1"]     # position k = MCAN k; fewer than 4: the rest unconnected
    flash = "ecan-flash.bin"        # optional; default <state dir>/<name>.flash
    serial = 1                      # optional, 0x1018:04

It joins the ``[ethercat]`` segment like ``ethercat_io`` (``is_ethercat`` + ``slave``) and is listed
in the ready file's ``ethercat.slaves``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gatewaylab.bus.controller import Controller
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext, section_error, state_file

__all__ = ["KEYS", "KIND", "EcanLiteParticipant", "create_device"]


KEYS: dict[str, Key] = {
    "name": Key(str, "ecan"),
    "channels": Key(list, [], help='bus names, position k = MCAN k, e.g. ["can0", "can1"]'),
    "flash": Key(str, help="the configuration flash image; default <state dir>/<name>.flash"),
    "serial": Key(int, 0, min=0, max=0xFFFFFFFF, hex=True, help="the identity object's serial number"),
}


class EcanLiteParticipant:
    """The rig participant: one :class:`EcanLiteDevice`."""

    is_ethercat = True

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        where = f"[[device]] {cfg.get('name', 'ecan')}"
        cfg = KIND.validate(cfg, where, list(rig.buses))
        self.name: str = cfg["name"]
        channels = cfg["channels"]
        if len(channels) > 4 or not all(isinstance(c, str) and c for c in channels):
            raise section_error(where, f"channels must be at most 4 bus names, got {channels!r}")
        controllers: list[Controller | None] = []
        for k, bus_name in enumerate(channels):
            if bus_name not in rig.buses:
                raise section_error(where, f"channels[{k}] = {bus_name!r} names an unknown bus (declared: "
                                           f"{', '.join(rig.buses) or 'none'})")
            controllers.append(rig.bus(bus_name).attach(f"{self.name}.mcan{k}"))
        self.channels = list(channels)
        self._controllers = controllers
        flash = Path(cfg["flash"]) if cfg["flash"] else state_file(rig.state_dir, self.name, ".flash")
        self.flash_path = flash
        self.device = EcanLiteDevice(rig.clock, controllers, flash_path=flash, name=self.name, serial=cfg["serial"])

    @property
    def slave(self) -> Any:
        """The EtherCAT slave (the segment's view of the device)."""
        return self.device.slave

    def can_channels(self) -> dict[str, Controller]:
        """The CAN controller of each MCAN channel, for fault injection (docs/faults.md)."""
        return {f"mcan{k}": c for k, c in enumerate(self._controllers) if c is not None}

    def start(self) -> None:
        """Nothing to open: the segment owns the wire, the buses deliver frames."""

    def stop(self) -> None:
        """Nothing to release."""

    def ready_info(self) -> dict[str, Any]:
        """The rig's ready line: this device's channels and flash file."""
        return {"ecanlite": {self.name: {"channels": self.channels, "flash": str(self.flash_path)}}}


def create_device(rig: RigContext, cfg: dict[str, Any]) -> EcanLiteParticipant:
    """The ``ecanlite`` kind's factory: one participant from its validated table."""
    return EcanLiteParticipant(rig, cfg)


KIND = DeviceKind("ecanlite", create_device, KEYS,
                  summary="ECAN-Lite EtherCAT to 4 x CAN FD gateway (joins the [ethercat] segment)")
