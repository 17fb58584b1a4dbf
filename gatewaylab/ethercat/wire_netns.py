"""A veth pair with one end in a fresh network namespace: where a master (SOEM, KickCAT) runs
against the emulator's wire transport without touching any real interface.

Used by ``gatewaylab migrate compare --wire``, the wire tests (tests/wire_kit.py) and the wire
benchmarks (benchmarks/wire.py): :func:`net_unavailable` says why this process cannot (not Linux,
no iproute2, no CAP_NET_ADMIN / CAP_NET_RAW, a master library missing), :func:`veth_namespace`
makes the namespace and the pair and removes both on every exit path, SIGTERM included.
"""

from __future__ import annotations

import contextlib
import importlib.util
import itertools
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

__all__ = ["net_unavailable", "veth_namespace"]

#: one counter per process, so two pairs made by one process never share a name
_names = itertools.count()


def net_unavailable(*modules: str) -> str | None:
    """None when this process may create namespaces and raw sockets (and can import ``modules``),
    else the reason it cannot."""
    if not sys.platform.startswith("linux"):
        return "needs Linux (AF_PACKET sockets, network namespaces)"
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


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@contextlib.contextmanager
def veth_namespace(ns_prefix: str, if_prefix: str) -> Iterator[tuple[str, str, str]]:
    """(namespace, emulator end here, master end inside the namespace), both ends up; the pair and
    the namespace are deleted on exit (on the main thread SIGTERM becomes SystemExit meanwhile, so
    a stopped run cleans up too). Interface names stay under Linux's 15 characters."""
    tag = f"{os.getpid() % 100000}{next(_names)}"
    ns, emu, mst = f"{ns_prefix}{tag}", f"{if_prefix}{tag}e", f"{if_prefix}{tag}m"
    previous: Any = None
    if threading.current_thread() is threading.main_thread():
        def terminate(signum: int, frame: FrameType | None) -> None:
            raise SystemExit(128 + signum)
        previous = signal.signal(signal.SIGTERM, terminate)
    try:
        _ip("netns", "add", ns)
        try:
            _ip("link", "add", emu, "type", "veth", "peer", "name", mst, "netns", ns)
            _ip("link", "set", emu, "up")
            _ip("netns", "exec", ns, "ip", "link", "set", mst, "up")
            yield ns, emu, mst
        finally:
            subprocess.run(["ip", "link", "del", emu], check=False, capture_output=True)
            subprocess.run(["ip", "netns", "del", ns], check=False, capture_output=True)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
