"""``gatewaylab net up|down [NAME]``: a veth pair for a local EtherCAT master (needs root / CAP_NET_ADMIN)."""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError, LocalError

__all__ = [
    "CAP_NET_ADMIN",
    "DEFAULT_NAME",
    "DESCRIPTION",
    "MAX_IFNAME",
    "NetFailed",
    "NetUsage",
    "add_subcommand",
    "has_net_admin",
    "net_down",
    "net_up",
    "peer_name",
]


DEFAULT_NAME = "gl-ecat"
MAX_IFNAME = 15


class NetUsage(ConfigError, ValueError):
    """A name ``gatewaylab net`` cannot use (exit 2); a ValueError for callers that expect one."""


class NetFailed(LocalError, OSError):
    """``ip`` refused to add, set up or delete an interface (exit 1); an OSError for callers that expect one."""
CAP_NET_ADMIN = 12

#: ``gatewaylab net --help``: plain text (argparse prints it as is).
DESCRIPTION = """\
Create or remove a veth pair for a local EtherCAT master. Needs root or CAP_NET_ADMIN.

  up NAME    creates NAME (give it to the rig file's [ethercat] interface) and its peer NAME-m
             (give that to the master: SOEM, pysoem, IgH generic driver), brings both up and
             turns IPv6 off on them, so the kernel sends no router solicitations into the line.
  down NAME  removes the pair again.

Example:
  sudo gatewaylab net up gl-ecat      # then: interface = "gl-ecat" in the rig file
"""


def has_net_admin(status: str | None = None) -> bool:
    """Root or CAP_NET_ADMIN in the effective set (``CapEff`` of /proc/self/status)."""
    if status is None:
        try:
            status = Path("/proc/self/status").read_text()
        except OSError:
            return os.geteuid() == 0
    for line in status.splitlines():
        if line.startswith("CapEff:"):
            return bool(int(line.split()[1], 16) >> CAP_NET_ADMIN & 1)
    return os.geteuid() == 0


def peer_name(name: str) -> str:
    """The master-side name of the veth pair whose emulator side is ``name``."""
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
    """Create the veth pair ``name``/``name-m`` and bring both ends up (IPv6 off); (emulator, master) names."""
    peer = peer_name(name)
    if len(peer) > MAX_IFNAME:
        raise NetUsage(f"interface names are at most {MAX_IFNAME} characters: {peer!r}")
    r = _ip("link", "add", name, "type", "veth", "peer", "name", peer)
    if r.returncode != 0:
        raise NetFailed(r.stderr.strip() or f"ip link add {name} failed")
    for iface in (name, peer):
        _disable_ipv6(iface)
        r = _ip("link", "set", iface, "up")
        if r.returncode != 0:
            raise NetFailed(r.stderr.strip())
    return name, peer


def net_down(name: str) -> None:
    """Delete the veth pair (deleting one end removes both); NetUsage when there is no such interface."""
    if not Path("/sys/class/net", name).exists():
        raise NetUsage(f"no such network interface {name!r} (`ip link` lists them)")
    r = _ip("link", "del", name)
    if r.returncode != 0:
        raise NetFailed(r.stderr.strip() or f"ip link del {name} failed")


def _cmd(args: argparse.Namespace) -> int:
    if not has_net_admin():
        print(f"error: gatewaylab net {args.action} needs root or CAP_NET_ADMIN "
              f"(try: sudo gatewaylab net {args.action} {args.name})", file=sys.stderr)
        return 1
    if shutil.which("ip") is None:
        print("error: the 'ip' tool (iproute2) is missing (apt-get install iproute2)", file=sys.stderr)
        return 1
    try:
        if args.action == "up":
            emulator, master = net_up(args.name)
            print(f"emulator interface: {emulator}")
            print(f"master interface:   {master}")
        else:
            net_down(args.name)
            print(f"removed {args.name} and {peer_name(args.name)}")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    return 0


def add_subcommand(subparsers: Any) -> None:
    """Register ``gatewaylab net up|down`` (cli/main.py EXTRA_SUBCOMMANDS)."""
    p = subparsers.add_parser("net", help="create/remove a veth pair for a local EtherCAT master",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=["up", "down"])
    p.add_argument("name", nargs="?", default=DEFAULT_NAME,
                   help=f"emulator-side interface (default {DEFAULT_NAME}); the master side is NAME-m")
    p.set_defaults(func=_cmd)
