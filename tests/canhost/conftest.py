"""Fixtures of the python-can-over-EtherCAT tests: a veth pair in a test-made network namespace
for the pysoem runs (the master side runs in the driver script ``canhost_driver.py`` inside it)."""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

_counter = itertools.count()


def _net_capable() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip."""
    if not sys.platform.startswith("linux"):
        return "EtherCAT wire tests need Linux AF_PACKET sockets"
    if shutil.which("ip") is None:
        return "the 'ip' tool (iproute2) is missing"
    try:
        import pysoem  # noqa: F401
    except ImportError:
        return "pysoem is not installed"
    try:
        status = Path("/proc/self/status").read_text()
        cap_eff = int(next(line for line in status.splitlines() if line.startswith("CapEff:")).split()[1], 16)
    except (OSError, StopIteration, ValueError):
        return "cannot read process capabilities"
    if not (cap_eff >> 12) & 1 or not (cap_eff >> 13) & 1:
        return "process lacks CAP_NET_ADMIN/CAP_NET_RAW (run as root to create veth pairs)"
    return None


@dataclass(frozen=True)
class CanhostVeth:
    """Emulator end in this namespace, master end inside ``namespace``."""

    namespace: str
    emulator_iface: str
    master_iface: str


@pytest.fixture(scope="module")
def canhost_veth() -> Iterator[CanhostVeth]:
    reason = _net_capable()
    if reason is not None:
        pytest.skip(reason)
    tag = f"{os.getpid() % 100000}{next(_counter)}"
    ns, emu, mst = f"gl-ch-{tag}", f"glc{tag}e", f"glc{tag}m"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        subprocess.run(["ip", "link", "add", emu, "type", "veth", "peer", "name", mst, "netns", ns], check=True)
        subprocess.run(["ip", "link", "set", emu, "up"], check=True)
        subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", mst, "up"], check=True)
        yield CanhostVeth(ns, emu, mst)
    finally:
        subprocess.run(["ip", "link", "del", emu], check=False, capture_output=True)
        subprocess.run(["ip", "netns", "del", ns], check=False)
