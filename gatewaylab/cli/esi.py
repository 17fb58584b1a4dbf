"""``gatewaylab esi KIND -o FILE``: the ESI (ETG.2000) file of one of gatewaylab's EtherCAT device kinds.

The file describes the slave exactly as it runs (identity, SII configuration, SyncManagers, PDOs, the
whole CoE dictionary), so a configuration tool imports what the master finds online, and ``kind =
"esi"`` run from it gives a slave a master cannot tell from the original.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esi import export_esi
from gatewaylab.ethercat.slave import Slave

__all__ = ["ESI_KINDS", "add_subcommand", "cmd_esi", "kind_slave"]


def _ecanlite() -> Slave:
    from gatewaylab.devices.ecanlite.device import EcanLiteDevice
    return EcanLiteDevice(SimulatedClock(), []).slave


def _esd() -> Slave:
    from gatewaylab.devices.esd_can_ethercat.device import create_esd_gateway
    return create_esd_gateway(SimulatedClock(), None, start=False).slave


def _io() -> Slave:
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    return create_io_slave(SimulatedClock())


def _drive() -> Slave:
    from gatewaylab.devices.ethercat_drive.device import EthercatDrive
    drive = EthercatDrive(SimulatedClock())
    drive.stop()
    return drive.slave


#: Rig-file kind -> a fresh, unconnected slave of it with its default settings.
ESI_KINDS: dict[str, Callable[[], Slave]] = {
    "ecanlite": _ecanlite, "esd_can_ethercat": _esd, "ethercat_io": _io, "ethercat_drive": _drive,
}


def kind_slave(kind: str) -> Slave:
    """A slave of ``kind`` as ``gatewaylab run`` builds it with default keys."""
    factory = ESI_KINDS.get(kind)
    if factory is None:
        raise ConfigError(f"{kind!r} is not an EtherCAT device kind (known: {', '.join(ESI_KINDS)})")
    return factory()


def cmd_esi(args: argparse.Namespace) -> int:
    """Write the ESI of ``args.kind`` to ``args.output``."""
    slave = kind_slave(args.kind)
    out = Path(args.output)
    if not out.parent.is_dir():
        raise ConfigError(f"-o {args.output}: folder {out.parent} does not exist")
    d = slave.desc if args.name is None else replace(slave.desc, name=args.name)
    if args.name is not None and (0x1008, 0) in slave.od.entries:
        slave.od.set(0x1008, 0, args.name)      # the device name object carries it too, as the rig's slave does
    out.write_text(export_esi(d, slave.od), encoding="utf-8")
    print(f"{out}: ESI of {args.kind} ({d.name}, vendor 0x{d.vendor_id:X} product 0x{d.product_code:X} "
          f"revision 0x{d.revision:X}, {len(slave.od)} objects)")
    return 0


def add_subcommand(sub: Any) -> None:
    """Register ``gatewaylab esi`` (cli/main.py EXTRA_SUBCOMMANDS)."""
    p = sub.add_parser("esi", help="write the ESI file of an EtherCAT device kind",
                       description="Write the ESI (ETG.2000 XML) of one of gatewaylab's EtherCAT device kinds; "
                                   '`kind = "esi"` in a rig file runs a slave from it.')
    p.add_argument("kind", metavar="KIND", choices=sorted(ESI_KINDS), help=", ".join(sorted(ESI_KINDS)))
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="the ESI file to write")
    p.add_argument("--name", help="the device name the ESI and its SII carry (default: the kind's); a rig "
                                  "names its ethercat_io / ethercat_drive slaves' SII after the device")
    p.set_defaults(func=cmd_esi)
