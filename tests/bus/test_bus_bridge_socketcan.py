"""``[[bridge]] interface = "socketcan"`` against can-utils on a vcan interface (issue 24, SocketCAN): a
frame sent with ``cansend`` reaches a drive on the rig, its answer is seen by ``candump``. The vcan
interface lives in a network namespace the test creates; where the kernel has no vcan module or
can-utils are missing the test is skipped with that reason."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from bridge_kit import bridge_rig

from gatewaylab.rig.process import RigProcess

RIG = bridge_rig("socketcan", "vcan0")


def _vcan_unavailable() -> str | None:
    if not sys.platform.startswith("linux") or shutil.which("ip") is None or shutil.which("unshare") is None:
        return "needs Linux with iproute2 and unshare"
    if os.geteuid() != 0:
        return "needs root to create a network namespace with a vcan interface"
    probe = subprocess.run(["unshare", "-n", "ip", "link", "add", "dev", "vcan0", "type", "vcan"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        return (f"the kernel has no vcan module ('ip link add type vcan': {probe.stderr.strip()}); "
                f"load it with 'modprobe vcan'")
    for tool in ("candump", "cansend"):
        if shutil.which(tool) is None:
            return f"can-utils is not installed ({tool} missing; apt-get install can-utils)"
    return None


@contextlib.contextmanager
def vcan_namespace() -> Iterator[str]:
    ns = f"glv{os.getpid() % 100000}"
    subprocess.run(["ip", "netns", "add", ns], check=True, capture_output=True)
    try:
        for cmd in (["link", "add", "dev", "vcan0", "type", "vcan"], ["link", "set", "vcan0", "up"],
                    ["link", "set", "lo", "up"]):
            subprocess.run(["ip", "-n", ns, *cmd], check=True, capture_output=True)
        yield ns
    finally:
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)


UNAVAILABLE = _vcan_unavailable()


@pytest.mark.net
@pytest.mark.skipif(UNAVAILABLE is not None, reason=str(UNAVAILABLE))
def test_cansend_and_candump_reach_a_drive_through_a_socketcan_bridge(tmp_path: Path) -> None:
    """CiA 301 SDO expedited upload of 0x1000 (device type) by cansend on vcan0: the drive on the rig
    answers 0x582 43 00 10 00 ..., which candump on vcan0 prints."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG)
    with vcan_namespace() as ns, RigProcess(rig_file, workdir=tmp_path, prefix=("ip", "netns", "exec", ns)) as rig:
        assert rig.info["bridges"]["bridge-can0-socketcan"]["state"] == "up"
        dump = subprocess.Popen(["ip", "netns", "exec", ns, "candump", "-L", "-n", "1", "-T", "10000",
                                 "vcan0,582:7FF"], stdout=subprocess.PIPE, text=True)
        out = ""
        try:
            for _ in range(5):                 # candump may still be starting: ask again until it prints
                subprocess.run(["ip", "netns", "exec", ns, "cansend", "vcan0", "602#4000100000000000"], check=True,
                               timeout=10)
                try:
                    out, _ = dump.communicate(timeout=3)
                    break
                except subprocess.TimeoutExpired:
                    continue
        finally:
            if dump.poll() is None:
                dump.kill()
                dump.wait()
        assert "582#43001000" in out, out
