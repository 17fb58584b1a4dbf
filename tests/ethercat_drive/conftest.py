"""Fixtures of the ethercat_drive tests: a veth pair inside a network namespace the test creates
and deletes (the pattern of tests/ethercat/conftest.py), for pysoem / KickCAT in a subprocess."""

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
        status = Path("/proc/self/status").read_text()
        cap_eff = int(next(line for line in status.splitlines() if line.startswith("CapEff:")).split()[1], 16)
    except (OSError, StopIteration, ValueError):
        return "cannot read process capabilities"
    if not (cap_eff >> 12) & 1 or not (cap_eff >> 13) & 1:
        return "process lacks CAP_NET_ADMIN/CAP_NET_RAW (run as root to create veth pairs)"
    return None


@dataclass(frozen=True)
class DriveVeth:
    """Emulator end in this namespace, master end inside ``namespace``."""

    namespace: str
    emulator_iface: str
    master_iface: str

    def run(self, script: Path, *args: str, timeout: float = 180.0) -> subprocess.CompletedProcess[str]:
        """Run a Python script inside the namespace with the master interface as first argument."""
        return subprocess.run(["ip", "netns", "exec", self.namespace, sys.executable, str(script),
                               self.master_iface, *args], capture_output=True, text=True, timeout=timeout,
                              check=False)


@pytest.fixture(scope="module")
def drive_veth() -> Iterator[DriveVeth]:
    reason = _net_capable()
    if reason is not None:
        pytest.skip(reason)
    tag = f"{os.getpid() % 100000}{next(_counter)}"
    ns = f"gl-ecd-{tag}"
    emu, mst = f"gld{tag}e", f"gld{tag}m"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        subprocess.run(["ip", "link", "add", emu, "type", "veth", "peer", "name", mst, "netns", ns], check=True)
        subprocess.run(["ip", "link", "set", emu, "up"], check=True)
        subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", mst, "up"], check=True)
        yield DriveVeth(ns, emu, mst)
    finally:
        subprocess.run(["ip", "link", "del", emu], check=False, capture_output=True)
        subprocess.run(["ip", "netns", "del", ns], check=False)
