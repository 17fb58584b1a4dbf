"""Fixtures of the ethercat_drive tests: a veth pair inside a network namespace the test creates
and deletes (the pattern of tests/ethercat/conftest.py), for pysoem / KickCAT in a subprocess."""

from __future__ import annotations

import itertools
import os
import subprocess
from collections.abc import Iterator

import pytest
from ecdrive_testkit import DriveVeth, net_capable

_counter = itertools.count()


@pytest.fixture(scope="module")
def drive_veth() -> Iterator[DriveVeth]:
    reason = net_capable()
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
