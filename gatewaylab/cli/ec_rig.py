"""``gatewaylab ec``: the EtherCAT verbs of ``gatewaylab.cli.ec`` with ``--rig`` support.

The verbs live in the EtherCAT layer; building a rig from a file belongs to this layer, so it is
handed down here (the layering of docs/architecture.md: ethercat never imports rig).
"""

from __future__ import annotations

from typing import Any

from gatewaylab.cli import ec as ec_cli
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.rig.runtime import Rig


def open_rig(path: str) -> Rig:
    """The rig of ``path`` on a simulated clock, without bus endpoints or wires, started."""
    rig = Rig.from_file(path, clock=SimulatedClock(), endpoints=False)
    try:
        rig.start()
    except BaseException:
        rig.close()
        raise
    return rig


def add_subcommand(subparsers: Any) -> None:
    """Register ``gatewaylab ec`` (rig/cli.py EXTRA_SUBCOMMANDS)."""
    ec_cli.add_subcommand(subparsers, open_rig=open_rig)
