"""``[ethercat] eni = "PATH"`` and ``esi = [...]``: the segment the ENI describes, in the ENI's order.

Each ENI ``<Slave>`` becomes, in this order of preference: a rig ``[[device]]`` on the segment with the same
vendor id and product code (the first such device not placed yet, in rig-file order: the rig's own
ECAN-Lite, or a ``kind = "esi"`` device with behaviour rules), a slave from its ESI
(:class:`~gatewaylab.devices.esi.eni_segment.EsiCatalogue`), or a slave from the ENI alone. A rig device that
matches no ENI slave is an error: the ENI describes the whole segment. One log line per slave says where it
came from; the ready file lists them under ``eni``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esi.eni_segment import ENI_ONLY, EsiCatalogue, Origin, build_eni_slave, slave_name
from gatewaylab.devices.esi.files import EsiFiles
from gatewaylab.ethercat.eni import Eni, EniError, parse_eni_xml
from gatewaylab.ethercat.slave import Slave
from gatewaylab.plugin.capabilities import EthercatDevice
from gatewaylab.plugin.participant import RigContext

__all__ = ["EniSegment", "build_eni_segment", "read_eni_file"]

_log = logging.getLogger(__name__)


def read_eni_file(path: Path) -> Eni:
    """Read and parse an ENI file (one :class:`EniError` line when it cannot be used)."""
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise EniError(f"{path}: is a folder, not an ENI file") from None
    except OSError as exc:
        raise EniError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    return parse_eni_xml(data, str(path))


class EniSegment:
    """The slaves of an ENI segment in position order and where each came from."""

    def __init__(self, eni: Eni, slaves: list[Slave], origins: list[Origin], devices: list[EthercatDevice]) -> None:
        self.eni = eni
        self.slaves = slaves
        self.origins = origins
        #: the rig's devices placed in the segment, in position order
        self.devices = devices

    def states(self) -> dict[str, Any]:
        """AL state, error flag, AL status code and origin of the slaves built from the ENI (the rig's own
        devices are listed by their participants): the control request ``ethercat-states``."""
        placed = {id(d.slave) for d in self.devices}
        out: dict[str, Any] = {}
        for slave, origin in zip(self.slaves, self.origins, strict=True):
            if id(slave) in placed:
                continue
            status = slave.esc.al_status
            state = {1: "INIT", 2: "PREOP", 3: "BOOT", 4: "SAFEOP", 8: "OP"}.get(status & 0x0F, f"0x{status & 0x0F:X}")
            out[slave.name] = {"state": state, "error": bool(status & 0x10), "code": slave.esc.al_status_code,
                               "from": origin.file or origin.match}
        return out

    def info(self) -> dict[str, Any]:
        """The ready file's ``eni`` table: the file and one row per slave."""
        return {"file": self.eni.source, "expected_wkc": self.eni.cyclic_wkc, "slaves": [
            {"position": o.position, "name": o.name, "match": o.match, "file": o.file, "type": o.type_name}
            for o in self.origins]}


def _path(base: Path, text: str) -> Path:
    path = Path(text).expanduser()
    return path if path.is_absolute() else base / path


def build_eni_segment(rig: RigContext, eni_text: str, esi: Sequence[Any] | None,
                      devices: Sequence[EthercatDevice]) -> EniSegment:
    """Build the segment of ``eni_text`` (relative to the rig's folder) with the ESI files and folders of
    ``esi`` and the rig's EtherCAT ``devices``."""
    if esi is not None and not all(isinstance(e, str) and e for e in esi):
        raise ConfigError(f"[ethercat] esi must be a list of file or folder names, got {esi!r}")
    eni = read_eni_file(_path(rig.base_dir, eni_text))
    catalogue = EsiCatalogue([_path(rig.base_dir, e) for e in esi or []], rig.build_cache.part(EsiFiles))
    free = list(devices)
    taken = {d.name for d in devices}
    slaves: list[Slave] = []
    origins: list[Origin] = []
    placed: list[EthercatDevice] = []
    missing: set[tuple[int, int, int]] = set()
    for s in eni.slaves:
        device = next((d for d in free if (d.slave.desc.vendor_id, d.slave.desc.product_code)
                       == (s.vendor_id, s.product_code)), None)
        if device is not None:
            free.remove(device)
            placed.append(device)
            slaves.append(device.slave)
            origins.append(Origin(s.position, device.name, "device", None, device.slave.desc.name))
        else:
            slave, origin = build_eni_slave(rig.clock, s, slave_name(s.name, taken), catalogue, eni.source)
            slaves.append(slave)
            origins.append(origin)
            if origin.match == ENI_ONLY and s.identity not in missing:
                missing.add(s.identity)
                _log.warning("%s: no ESI for vendor 0x%X product 0x%X revision 0x%X (%s, line %d): built from the "
                             "ENI alone", eni.source, *s.identity, s.name, s.line)
            elif origin.match.startswith("revision") and s.identity not in missing:
                missing.add(s.identity)
                _log.warning("%s: %s: no ESI of revision 0x%X; %s", eni.source, s.name, s.revision, origin.match)
        _log.info("%s", origins[-1].line())
    if free:
        names = ", ".join(f"{d.name} (vendor 0x{d.slave.desc.vendor_id:X} product 0x{d.slave.desc.product_code:X})"
                          for d in free)
        raise ConfigError(f"[ethercat] eni = {eni_text!r}: the rig's EtherCAT devices {names} match no <Slave> of "
                          f"{eni.source} by vendor id and product code (an ENI describes the whole segment)")
    return EniSegment(eni, slaves, origins, placed)
