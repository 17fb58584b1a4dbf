"""canopen SDO uploads/s through each EtherCAT gateway's python-can interface, next to the same
uploads on the plain ``gatewaylab`` bus interface, in one run.

One rig file: a 500 kbit/s bus with an esd CAN-EtherCAT (position 0), an ECAN-Lite (position 1,
MCAN channel 0 on the bus) and a CiA 402 drive (node 2). The same canopen application reads
0x1000 'Device type' (expedited SDO upload) and 0x1008 'Manufacturer device name' (segmented):

* ``interface="gatewaylab"``: the rig runs as ``gatewaylab run`` (real time) and the client
  reaches the bus over the socket endpoint (the plain interface, no gateway in the path);
* ``interface="esd_can_ethercat"`` / ``"ecanlite"``, ``channel="rig:RIG.toml"``: the rig in
  process on a simulated clock, every frame through the gateway's process data at 1 kHz
  (``send()`` runs the cycles until the answer is back).

The gateway rows also print simulated milliseconds per upload (the EtherCAT cycles the request
and its answer take: what a real line at cycle_us = 1000 would cost).
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import canopen

RIG = """
[[bus]]
name = "can0"
bitrate = 500000

[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"

[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can0"]

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
"""
N = 300
N_SEGMENTED = 50


def _rates(net: canopen.Network) -> dict[str, float]:
    node = net.add_node(2, canopen.ObjectDictionary())  # type: ignore[no-untyped-call]
    node.sdo.upload(0x1000, 0)                      # warm up
    host = getattr(net.bus, "host", None)
    sim0 = host.clock.now() if host is not None else 0.0
    times = []
    for _ in range(N):
        t0 = time.perf_counter()
        node.sdo.upload(0x1000, 0)
        times.append(time.perf_counter() - t0)
    sim = (host.clock.now() - sim0) / N if host is not None else 0.0
    t0 = time.perf_counter()
    for _ in range(N_SEGMENTED):
        node.sdo.upload(0x1008, 0)
    seg = N_SEGMENTED / (time.perf_counter() - t0)
    return {"expedited": 1.0 / statistics.median(times), "segmented": seg, "sim_ms": sim * 1e3}


def _gatewaylab(tmp: Path, rig: Path) -> dict[str, float]:
    ready = tmp / "ready.json"
    proc = subprocess.Popen([sys.executable, "-m", "gatewaylab", "run", str(rig), "--ready-file", str(ready)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        while b"bus can0" not in proc.stdout.readline():
            pass
        endpoint = json.loads(ready.read_text())["buses"]["can0"]["endpoint"]
        net = canopen.Network()
        net.NOTIFIER_CYCLE = 0.05
        net.connect(interface="gatewaylab", channel=endpoint)
        try:
            return _rates(net)
        finally:
            net.disconnect()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _gateway(interface: str, rig: Path, **kwargs: Any) -> dict[str, float]:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface=interface, channel=f"rig:{rig}", bitrate=500_000, cycle_us=1000, **kwargs)
    try:
        return _rates(net)
    finally:
        net.disconnect()


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        rig = tmp / "rig.toml"
        rig.write_text(RIG)
        rows = {"gatewaylab (plain bus, socket)": _gatewaylab(tmp, rig),
                "esd_can_ethercat (rig:, 1 kHz)": _gateway("esd_can_ethercat", rig, slave=0),
                "ecanlite (rig:, 1 kHz)": _gateway("ecanlite", rig, slave=1, can_channel=0, pdo_n=3)}
    base = rows["gatewaylab (plain bus, socket)"]["expedited"]
    print(f"canopen SDO uploads/s of node 2 ({N} expedited 0x1000, {N_SEGMENTED} segmented 0x1008), one run:")
    for name, r in rows.items():
        sim = f"  {r['sim_ms']:5.1f} simulated ms/upload" if r["sim_ms"] else ""
        print(f"  {name:32s} expedited {r['expedited']:7.0f}/s ({r['expedited'] / base:4.2f}x plain)  "
              f"segmented {r['segmented']:6.0f}/s{sim}")


if __name__ == "__main__":
    main()
