"""``[[device]] kind = "ethercat_io"``: the generic loop-back I/O slave in the rig's ``[ethercat]`` segment.

Rig file::

    [[device]]
    kind = "ethercat_io"
    name = "io1"           # optional; serial = 1, revision = 1 optional
"""

from __future__ import annotations

from typing import Any

from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.plugin import DeviceKind, Key, RigContext

__all__ = ["KEYS", "KIND", "IoDevice", "create_io_device"]


KEYS: dict[str, Key] = {
    "name": Key(str, "ethercat_io"),
    "serial": Key(int, 0, min=0, max=0xFFFFFFFF, hex=True, help="the identity object's serial number"),
    "revision": Key(int, 1, min=0, max=0xFFFFFFFF, hex=True),
}

class IoDevice:
    """``[[device]] kind = "ethercat_io"``: the generic loop-back I/O slave."""

    is_ethercat = True

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        cfg = KIND.validate(cfg, f"[[device]] {cfg.get('name', 'ethercat_io')}")
        self.name: str = cfg["name"]
        self.slave = create_io_slave(rig.clock, self.name, serial=cfg["serial"], revision=cfg["revision"])

    def start(self) -> None:
        """Nothing to open: the segment owns the wire."""

    def stop(self) -> None:
        """Nothing to release."""

    def ready_info(self) -> dict[str, Any]:
        """Nothing for the ready file: a master finds the I/O slave on the segment by its identity."""
        return {}


def create_io_device(rig: RigContext, cfg: dict[str, Any]) -> IoDevice:
    """The factory :data:`KIND` hands the rig: one I/O slave per ``[[device]]`` section."""
    return IoDevice(rig, cfg)


KIND = DeviceKind("ethercat_io", create_io_device, KEYS,
                     summary="the generic EtherCAT loop-back I/O slave (joins the [ethercat] segment)")
