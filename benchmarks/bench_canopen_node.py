"""EDS-built CANopen nodes under SYNC: 32 ``canopen_node`` devices on one 1 Mbit/s bus, each with 2
synchronous TPDOs, SYNC at 1 kHz, on the simulated clock (CPU per SYNC cycle, TPDOs missed).

A 1 Mbit/s bus carries about 8,000 8-byte frames per second, so 64 TPDOs after every 1 ms SYNC (the
case as first asked for) cannot fit any real bus: each TPDO is sent every ``every``-th SYNC
(transmission type ``every``), default 10, which loads the bus to about 80 %. The run counts what each
node sent and what a listener received: a missed TPDO is one the bus never carried.
GL_BENCH_NODE_COUNT (32), GL_BENCH_NODE_EVERY (10), GL_BENCH_NODE_SECONDS (2.0 simulated seconds).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from gatewaylab.bus import CanFrame
from gatewaylab.cli.eds import eds_of
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig


def _rig(folder: Path, nodes: int, clock: SimulatedClock) -> Rig:
    eds = folder / "node.eds"
    eds.write_text(eds_of("drive", 1))
    devices = []
    for i in range(nodes):
        node_id = 1 + i
        devices.append({"kind": "canopen_node", "eds": str(eds), "bus": "can0", "node_id": node_id,
                        "name": f"n{node_id}",
                        "behaviour": {"0x6064": "counter", "0x606C": {"sine": {"amplitude": 1000, "period": 0.5}}}})
    return Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "bitrate": 1_000_000, "endpoint": "none"}],
                          "device": devices}), clock=clock)


def run(nodes: int = 32, every: int = 10, seconds: float = 2.0) -> dict[str, float]:
    """Build the rig, configure TPDO 1 and 2 of each node synchronous every ``every`` SYNC, run."""
    clock = SimulatedClock()
    with tempfile.TemporaryDirectory() as tmp, _rig(Path(tmp), nodes, clock) as rig:
        rig.start()
        bus = rig.buses["can0"]
        received: dict[int, int] = {}

        def heard(frame: CanFrame, t: float) -> None:
            if 0x180 <= frame.can_id < 0x300:
                received[frame.can_id] = received.get(frame.can_id, 0) + 1

        master = bus.attach("master", on_frame=heard)
        for participant in rig.participants:
            node = participant.node  # type: ignore[attr-defined]
            # as a master's SDO downloads would (CiA 301 rules applied): TPDO 2 is invalid in the drive's EDS
            cob2 = 0x280 + node.node_id
            node.write(0x1801, 1, (cob2 | 0x80000000).to_bytes(4, "little"))
            for tpdo in (0x1800, 0x1801):
                node.write(tpdo, 2, bytes([every]))
            node.write(0x1801, 1, cob2.to_bytes(4, "little"))
        master.send(CanFrame(0x000, bytes([0x01, 0x00])))            # NMT start all
        clock.advance(0.01)
        cycles = int(seconds * 1000)
        cpu = time.process_time()
        for _ in range(cycles):
            master.send(CanFrame(0x080, b""))
            clock.advance(0.001)
        cpu = time.process_time() - cpu
        clock.advance(0.05)
        sent = sum(tp.sent for p in rig.participants for tp in p.node.pdo.tpdo)  # type: ignore[attr-defined]
        got = sum(received.values())
        expected = nodes * 2 * (cycles // every)
        return {"nodes": nodes, "every": every, "cycles": cycles, "expected": expected, "sent": sent,
                "received": got, "missed": max(0, expected - got), "cpu_us_per_sync": 1e6 * cpu / cycles,
                "bus_load": bus.load_percent()}


def main() -> None:
    """Print the run's figures."""
    nodes = int(os.environ.get("GL_BENCH_NODE_COUNT", "32"))
    every = int(os.environ.get("GL_BENCH_NODE_EVERY", "10"))
    seconds = float(os.environ.get("GL_BENCH_NODE_SECONDS", "2.0"))
    r = run(nodes, every, seconds)
    print(f"{r['nodes']} canopen_node devices from an EDS, 2 TPDOs each every {r['every']} SYNC, SYNC at 1 kHz, "
          f"{r['cycles']} cycles (simulated clock)")
    print(f"  TPDOs expected {r['expected']:,}, sent {r['sent']:,}, received {r['received']:,}, "
          f"missed {r['missed']:,}")
    print(f"  CPU per SYNC cycle: {r['cpu_us_per_sync']:.1f} us, bus load {r['bus_load']:.0f} %")


if __name__ == "__main__":
    main()
