"""Rig-file kind ``esi``: an EtherCAT slave from its ESI file, in the rig's ``[ethercat]`` segment.

```toml
[[device]]
kind = "esi"
esi = "Beckhoff EL2xxx.xml"   # relative to the rig file's folder
type = "EL2008"               # the ESI <Type>, when the file describes several devices
name = "do1"                  # optional (default: the type)
serial = 0x1234               # optional: SII and 0x1018:04
sii = "el2008.bin"            # optional: the EEPROM byte for byte (a dump)
transition_ms = { PREOP_SAFEOP = 150 }   # optional: a slow application (see devices/esi/esm.py)
[device.behaviour]
"0x6000:01" = { echo = "0x7000:01" }
```
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esi.device import EsiApplication, esi_slave
from gatewaylab.devices.esi.esm import parse_transition_ms
from gatewaylab.devices.esi.files import EsiFiles
from gatewaylab.devices.esi.reader import EsiDevice
from gatewaylab.ethercat.slave import Slave
from gatewaylab.plugin.behaviour import Behaviour, load_hook, parse_behaviour
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext

__all__ = ["KEYS", "KIND", "EsiParticipant", "create_esi_device", "default_name"]

log = logging.getLogger(__name__)

KEYS: dict[str, Key] = {
    "esi": Key(str, required=True, help="the ESI file, relative to the rig file's folder"),
    "type": Key(str, help="the ESI <Type> of the device, when the file describes several"),
    "product_code": Key(int, min=0, max=0xFFFFFFFF, hex=True, help="pick the device by product code"),
    "revision": Key(int, min=0, max=0xFFFFFFFF, hex=True, help="pick the device by revision"),
    "name": Key(str),
    "serial": Key(int, min=0, max=0xFFFFFFFF, hex=True, help="SII word 0x0E and 0x1018:04"),
    "sii": Key(str, help="an EEPROM dump used byte for byte, relative to the rig file's folder"),
    "behaviour": Key(dict, help="rules per input entry: echo, counter, sine, ramp, value, random"),
    "hook": Key(str, help="package.module:function called once per cycle with (values, t)"),
    "transition_ms": Key(dict, help="the application's time per transition (INIT_PREOP, INIT_BOOT, PREOP_SAFEOP, "
                         "SAFEOP_OP), ms; longer than the ESI's timeout less 10 % refuses it"),
}


def default_name(cfg: Mapping[str, Any]) -> str:
    """A slave's name when the rig file gives none: its type, else the file's stem."""
    text = str(cfg.get("type") or Path(str(cfg.get("esi", "esi"))).stem)
    return re.sub(r"[^A-Za-z0-9_.-]", "_", text).lstrip(".-") or "esi"


def _path(rig: RigContext, text: str) -> Path:
    path = Path(text).expanduser()
    return path if path.is_absolute() else rig.base_dir / path


class EsiParticipant:
    """``[[device]] kind = "esi"``: one slave of the ``[ethercat]`` segment."""

    is_ethercat = True

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        cfg = KIND.validate(cfg, f"[[device]] {cfg.get('name', 'esi')}")
        self.name: str = KIND.name_of(cfg) or default_name(cfg)
        self.source = _path(rig, cfg["esi"])
        files = rig.build_cache.part(EsiFiles)      # each file read once for the whole build
        self.device: EsiDevice = files.device(self.source, self.source.name, cfg["type"], cfg["product_code"],
                                              cfg["revision"])
        sii = _path(rig, cfg["sii"]) if cfg["sii"] else None
        slow = parse_transition_ms(cfg["transition_ms"] or {}, f"[[device]] {self.name}")
        self.slave: Slave = esi_slave(rig.clock, self.device, self.name, serial=cfg["serial"], sii_path=sii,
                                      transition_ms=slow, files=files)
        if cfg["behaviour"] or cfg["hook"]:
            try:
                rules = parse_behaviour(cfg["behaviour"] or {}, self.slave.od)
            except ConfigError as exc:
                raise ConfigError(f"[[device]] {self.name}: {exc}") from None
            hook = load_hook(cfg["hook"]) if cfg["hook"] else None
            app = self.slave.app
            assert isinstance(app, EsiApplication)
            app.behaviour = Behaviour(rules, self.slave.od, hook)
        for note in files.unsaid_notes(self.device):     # once per device type and build
            log.warning("%s: %s: %s", self.name, self.source.name, note)
        d = self.device.desc
        log.info("%s: %s from %s (vendor 0x%X product 0x%X revision 0x%X)%s", self.name, self.device.type_name,
                 self.source, d.vendor_id, d.product_code, d.revision,
                 "" if self.device.objects is not None else ", generic dictionary")

    def start(self) -> None:
        """Nothing to open: the segment owns the wire."""

    def stop(self) -> None:
        """Nothing to release."""

    def ready_info(self) -> dict[str, Any]:
        """Where the slave came from (the ESI file and its device type)."""
        return {"esi": {self.name: {"file": str(self.source), "type": self.device.type_name}}}


def create_esi_device(rig: RigContext, cfg: dict[str, Any]) -> EsiParticipant:
    """The factory :data:`KIND` hands the rig: one slave per ``[[device]]`` section."""
    return EsiParticipant(rig, cfg)


KIND = DeviceKind("esi", create_esi_device, KEYS,
                  summary="an EtherCAT slave from its ESI file (joins the [ethercat] segment)",
                  default_name=default_name)
