"""Simulated seconds per wall second: 10 CSP axes on 4 channels through one ECAN-Lite at 1 kHz.

Issue 12 benchmark (target >= 2x real time), in process on the simulated clock: the host library
(adapter + MCAN Port + CiA 402 layer, ``gatewaylab.devices.ecanlite.host``) on the in-process
master, the ECAN-Lite device, four 1 Mbit/s buses with 3 + 3 + 2 + 2 IDX-like drives. Every 1 ms:
one LRW, the TxPDO parsed, RPDO1 (controlword + target) per axis and a SYNC per bus written into
the RxPDO (N = 3), each drive answering TPDO1 on SYNC. The startup (NMT, CSP mapping by SDO through
the gateway, enable) is not timed. Also printed: WKC errors, parse errors, master_period, and the
position error of every axis after the move. ``GL_BENCH_SECONDS`` sets the simulated seconds.

Printed, not asserted.
"""

from __future__ import annotations

import os
import struct
import tempfile
import time
from pathlib import Path

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.drive import Drive
from gatewaylab.canopen.nmt import NmtCommand
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.host.adapter import AdapterConfig, EcanAdapter
from gatewaylab.devices.ecanlite.host.cia402 import Cia402
from gatewaylab.devices.ecanlite.host.demo import rig_axes, rig_toml
from gatewaylab.devices.ecanlite.host.port import ChannelConfig, McanPort, PortConfig
from gatewaylab.ethercat.backend import InProcessBackend
from gatewaylab.rig.runtime import Rig

LAYOUT = ((1, 2, 3), (4, 5, 6), (7, 8), (9, 10))


def run(sim_seconds: float, step: int = 20) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rig.toml"
        path.write_text(rig_toml(LAYOUT))
        rig = Rig.from_file(str(path), clock=SimulatedClock(), endpoints=False)
        try:
            rig.start()
            backend = InProcessBackend.from_rig(rig)
            positions, axes = rig_axes(rig, step)
            adapter = EcanAdapter(backend, AdapterConfig.for_positions(positions, 3, cycle_us=1000))
            port = McanPort(adapter, PortConfig({ch: ChannelConfig.classic() for ch in range(4)}))
            adapter.start()
            cia = Cia402(port, axes)
            cia.startup()
            cycles = round(sim_seconds / adapter.period)
            t0 = rig.clock.now()
            w0 = time.perf_counter()
            cia.run(cycles)
            wall = time.perf_counter() - w0
            sim = rig.clock.now() - t0
            cia.settle(0.5)
            errors = [abs(r.error) for r in cia.results()]
            period = adapter.master_period.summary(adapter.period)
            return {"axes": len(axes), "sim_s": sim, "wall_s": wall, "ratio": sim / wall,
                    "wkc_errors": adapter.wkc_errors, "parse_errors": port.parse_errors,
                    "max_pos_error": max(errors), "period_max_us": period["max_us"],
                    "reached": sum(r.reached() for r in cia.results())}
        finally:
            rig.close()


def baseline(sim_seconds: float, step: int = 20) -> float:
    """The same ten drives on four 1 Mbit/s buses, driven by a plain sans-I/O master on each bus
    (RPDO1 per drive + SYNC every 1 ms, no EtherCAT, no gateway): simulated s per wall s."""
    clock = SimulatedClock()
    plan = []
    for b, nodes in enumerate(LAYOUT):
        bus = VirtualBus(clock, f"can{b}", 1_000_000)
        drives = [Drive(clock, bus, n, 0x1000 + n, store_path=None) for n in nodes]
        for d in drives:
            d.start()
        plan.append((bus.attach(f"master{b}"), drives))
    clock.advance(0.01)
    for _master, drives in plan:
        for d in drives:
            node = d.node
            node.write(0x1800, 2, bytes([1]))
            node.write(0x1400, 2, bytes([1]))
            node.write(0x6060, 0, bytes([8]))
            for cw in (0x06, 0x07, 0x0F):
                node.write(0x6040, 0, struct.pack("<H", cw))
            node.nmt_command(NmtCommand.START_REMOTE_NODE)
    target = [0]
    sync = CanFrame(0x80, b"")

    def cycle() -> None:
        target[0] += step
        for master, drives in plan:
            for d in drives:
                master.send(CanFrame(0x200 + (d.node.node_id or 0), struct.pack("<Hi", 0x0F, target[0])))
            master.send(sync)

    clock.call_every(0.001, cycle, first=clock.now())
    start = clock.now()
    w0 = time.perf_counter()
    clock.run_until(start + sim_seconds)
    return sim_seconds / (time.perf_counter() - w0)


def main() -> None:
    seconds = float(os.environ.get("GL_BENCH_SECONDS", "2"))
    base = baseline(seconds)
    r = run(seconds)
    print(f"ECAN-Lite host, {r['axes']:.0f} CSP axes on 4 channels, 1 kHz, in process (simulated clock)")
    print(f"  {r['sim_s']:.2f} simulated s in {r['wall_s']:.2f} wall s: {r['ratio']:.2f}x real time (target >= 2x)")
    print(f"  baseline, the same drives and buses under a plain CAN master (no EtherCAT, no gateway): "
          f"{base:.2f}x real time; EtherCAT + gateway + host library take {1 - r['ratio'] / base:.0%} of the wall time")
    print(f"  WKC errors {r['wkc_errors']:.0f}, parse errors {r['parse_errors']:.0f}, master_period max "
          f"{r['period_max_us']:.1f} us, axes at target {r['reached']:.0f}/{r['axes']:.0f} "
          f"(largest position error {r['max_pos_error']:.0f} inc)")


if __name__ == "__main__":
    main()
