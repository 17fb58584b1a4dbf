"""``gatewaylab eds KIND -o FILE``: the EDS (CiA 306) of a CANopen device kind, as a master's tool loads it.

The dictionary is the one a rig builds for that kind (a rig of one device on the simulated clock), so
the file is what the running device answers over SDO; ``kind = "canopen_node"`` run from it gives the
same dictionary back (docs/bring-your-own-network.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import GatewaylabError

__all__ = ["KINDS", "add_subcommand", "cmd_eds", "eds_of"]

#: the CANopen kinds built in, each with the smallest section that builds one
KINDS: dict[str, dict[str, Any]] = {
    "drive": {"kind": "drive", "serial": 0x1002},
    "maxon_idx": {"kind": "maxon_idx", "serial": 0x2001, "usb": {"pty": False}},
}


def eds_of(kind: str, node_id: int = 2, *, dcf: bool = False) -> str:
    """The EDS (or DCF) text of a rig-built device of ``kind`` with ``node_id``."""
    from gatewaylab.plugin.capabilities import HasNode
    from gatewaylab.rig.config import parse_rig
    from gatewaylab.rig.runtime import Rig

    section = {**KINDS[kind], "bus": "can0", "node_id": node_id, "name": kind}
    rig = Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}], "device": [section]}))
    with rig:
        (device,) = (p for p in rig.participants if isinstance(p, HasNode))
        return device.node.to_eds(dcf=dcf)


def cmd_eds(args: argparse.Namespace) -> int:
    """Write the EDS of ``args.kind`` to ``args.output`` (standard output for ``-``)."""
    try:
        text = eds_of(args.kind, args.node_id, dcf=args.dcf)
    except GatewaylabError as exc:
        print(f"gatewaylab eds: {exc}", file=sys.stderr)
        return 1
    if args.output == "-":
        sys.stdout.write(text)
        return 0
    try:
        Path(args.output).write_text(text)
    except OSError as exc:
        print(f"gatewaylab eds: -o {args.output}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    return 0


def add_subcommand(subparsers: Any) -> None:
    """Add ``eds`` to the gatewaylab CLI."""
    p = subparsers.add_parser("eds", help="write the EDS of a CANopen device kind (drive, maxon_idx)",
                              description="Write the EDS (CiA 306) of a CANopen device kind: the dictionary the "
                                          "running device answers over SDO. --dcf adds the values and the "
                                          "node-ID ([DeviceComissioning]).")
    p.add_argument("kind", choices=sorted(KINDS), help="the device kind")
    p.add_argument("-o", "--output", default="-", metavar="FILE", help="where to write it (default: stdout)")
    p.add_argument("--node-id", type=int, default=2, choices=range(1, 128), metavar="1..127",
                   help="the node-ID its $NODEID entries and a DCF use (default 2)")
    p.add_argument("--dcf", action="store_true", help="write a DCF (ParameterValue, [DeviceComissioning])")
    p.set_defaults(func=cmd_eds)
