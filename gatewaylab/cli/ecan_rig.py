"""``gatewaylab ecan``: the ECAN-Lite commands with ``--rig`` support for the host programs.

The commands live in the devices layer; building a rig from a file belongs to this layer, so the
opener is handed down here (docs/architecture.md layering: devices never import rig).
"""

from __future__ import annotations

from typing import Any

from gatewaylab.cli import ecan as ecan_cli
from gatewaylab.cli.ec_rig import open_rig


def add_subcommand(subparsers: Any) -> None:
    """Register ``gatewaylab ecan`` (rig/cli.py EXTRA_SUBCOMMANDS)."""
    ecan_cli.add_subcommand(subparsers, open_rig=open_rig)
