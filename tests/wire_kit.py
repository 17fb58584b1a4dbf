"""The one veth-namespace kit of the wire tests (EtherCAT over a veth pair, pysoem/KickCAT in a namespace).

Every test package that puts a master on a veth pair uses these two: ``net_capable()`` says why a test must
skip (not Linux, no iproute2, no CAP_NET_ADMIN/CAP_NET_RAW, a master library missing) and
``veth_namespace()`` makes a namespace with the master's end of a fresh veth pair in it, and removes both
again, whatever the test did. Importable from every test folder (tests/ is on sys.path through
tests/conftest.py).
"""

from __future__ import annotations

import contextlib
import importlib.util
import itertools
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

#: one counter for the whole process: two packages' fixtures never make the same interface name
_counter = itertools.count()


def net_capable(*modules: str) -> str | None:
    """None when this process may create namespaces and raw sockets (and can import ``modules``), else the
    reason to skip."""
    if not sys.platform.startswith("linux"):
        return "EtherCAT wire tests need Linux AF_PACKET sockets"
    if shutil.which("ip") is None:
        return "the 'ip' tool (iproute2) is missing"
    for module in modules:
        if importlib.util.find_spec(module) is None:
            return f"{module} is not installed"
    try:
        status = Path("/proc/self/status").read_text()
        cap_eff = int(next(line for line in status.splitlines() if line.startswith("CapEff:")).split()[1], 16)
    except (OSError, StopIteration, ValueError):
        return "cannot read process capabilities"
    if not (cap_eff >> 12) & 1 or not (cap_eff >> 13) & 1:
        return "process lacks CAP_NET_ADMIN/CAP_NET_RAW (run as root to create veth pairs)"
    return None


@contextlib.contextmanager
def veth_namespace(ns_prefix: str, if_prefix: str) -> Iterator[tuple[str, str, str]]:
    """(namespace, emulator interface here, master interface inside the namespace), both ends up; the pair
    and the namespace are deleted on exit. Interface names stay under Linux's 15 characters."""
    tag = f"{os.getpid() % 100000}{next(_counter)}"
    ns, emu, mst = f"{ns_prefix}{tag}", f"{if_prefix}{tag}e", f"{if_prefix}{tag}m"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        subprocess.run(["ip", "link", "add", emu, "type", "veth", "peer", "name", mst, "netns", ns], check=True)
        subprocess.run(["ip", "link", "set", emu, "up"], check=True)
        subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", mst, "up"], check=True)
        yield ns, emu, mst
    finally:
        subprocess.run(["ip", "link", "del", emu], check=False, capture_output=True)
        subprocess.run(["ip", "netns", "del", ns], check=False)
