"""``gatewaylab net up|down [NAME]``: a veth pair for a local EtherCAT master (needs root / CAP_NET_ADMIN).

``up NAME`` creates NAME (give it to the rig file's ``[ethercat] interface``) and its peer NAME-m
(give that to the master: SOEM, pysoem, IgH generic driver), brings both up and turns IPv6 off on
them so the kernel does not send router solicitations into the EtherCAT line.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

DEFAULT_NAME = "gl-ecat"
MAX_IFNAME = 15


def peer_name(name: str) -> str:
    return f"{name}-m"


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=False)


def _disable_ipv6(iface: str) -> None:
    path = Path(f"/proc/sys/net/ipv6/conf/{iface}/disable_ipv6")
    try:
        path.write_text("1")
    except OSError:
        pass


def net_up(name: str) -> tuple[str, str]:
    peer = peer_name(name)
    if len(peer) > MAX_IFNAME:
        raise ValueError(f"interface names are at most {MAX_IFNAME} characters: {peer!r}")
    r = _ip("link", "add", name, "type", "veth", "peer", "name", peer)
    if r.returncode != 0:
        raise OSError(r.stderr.strip() or f"ip link add {name} failed")
    for iface in (name, peer):
        _disable_ipv6(iface)
        r = _ip("link", "set", iface, "up")
        if r.returncode != 0:
            raise OSError(r.stderr.strip())
    return name, peer


def net_down(name: str) -> None:
    r = _ip("link", "del", name)
    if r.returncode != 0:
        raise OSError(r.stderr.strip() or f"ip link del {name} failed")


def _cmd(args: argparse.Namespace) -> int:
    if shutil.which("ip") is None:
        print("error: the 'ip' tool (iproute2) is missing", file=sys.stderr)
        return 1
    try:
        if args.action == "up":
            emulator, master = net_up(args.name)
            print(f"emulator interface: {emulator}")
            print(f"master interface:   {master}")
        else:
            net_down(args.name)
            print(f"removed {args.name} and {peer_name(args.name)}")
    except (OSError, ValueError) as exc:
        print(f"error: {exc} (creating veth pairs needs root or CAP_NET_ADMIN)", file=sys.stderr)
        return 1
    return 0


def add_subcommand(subparsers: Any) -> None:
    p = subparsers.add_parser("net", help="create/remove a veth pair for a local EtherCAT master",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=["up", "down"])
    p.add_argument("name", nargs="?", default=DEFAULT_NAME,
                   help=f"emulator-side interface (default {DEFAULT_NAME}); the master side is NAME-m")
    p.set_defaults(func=_cmd)
