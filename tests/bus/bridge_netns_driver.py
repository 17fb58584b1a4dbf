"""Run inside a fresh network namespace (``unshare -n``) by test_bus_bridge.py: only ``lo`` exists, so
python-can's udp_multicast (which binds to every interface and joins its group on the default one)
stays on loopback. `gatewaylab run` bridges can0 to udp_multicast; a canopen client on the far side
reads the drive's 0x1008 and moves it. Prints OK and exits 0 when all of that worked."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import can
import canopen
from bridge_kit import bridge_rig

from gatewaylab.rig.process import RigProcess

GROUP = "239.74.163.2"
RIG = bridge_rig("udp_multicast", GROUP, "{ hop_limit = 0 }")


def main() -> int:
    names = [name for _, name in socket.if_nameindex()]
    if names != ["lo"]:
        print(f"not in a namespace of its own: interfaces {names}")
        return 1
    for cmd in (["ip", "link", "set", "lo", "up"], ["ip", "link", "set", "lo", "multicast", "on"],
                ["ip", "route", "add", "224.0.0.0/4", "dev", "lo"]):
        subprocess.run(cmd, check=True)
    folder = Path(tempfile.mkdtemp(prefix="glt-udp-"))
    (folder / "rig.toml").write_text(RIG)
    try:
        return run(folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run(folder: Path) -> int:
    with RigProcess(folder / "rig.toml", workdir=folder, timeout=60) as rig:
        assert rig.info["bridges"]["bridge-can0-udp_multicast"]["state"] == "up"
        network = canopen.Network(can.Bus(interface="udp_multicast", channel=GROUP, hop_limit=0))
        network.connect()
        try:
            node = network.add_node(2, rig.info["canopen"]["can0"]["axis2"]["eds"])
            name = node.sdo[0x1008].raw
            assert "gatewaylab" in name, name
            node.sdo[0x6060].raw = 1                      # profile position
            for cw in (0x06, 0x07, 0x0F):
                node.sdo[0x6040].raw = cw
            node.sdo[0x607A].raw = 2000
            node.sdo[0x6040].raw = 0x1F
            node.sdo[0x6040].raw = 0x0F
            for _ in range(2000):                         # paced by SDO round trips
                if node.sdo[0x6041].raw & 0x400:
                    break
            position = node.sdo[0x6064].raw
            assert abs(position - 2000) <= 100, position
        finally:
            network.disconnect()
    print(f"OK {name} moved to {position}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
