"""Simulated seconds per wall second: 10 CSP axes on 4 channels through one ECAN-Lite at 1 kHz.

Issue 12 benchmark (target >= 2x real time), in process on the simulated clock: the host library
(adapter + MCAN Port + CiA 402 layer, ``gatewaylab.hosts.ecanlite``) on the in-process
master, the ECAN-Lite device, four 1 Mbit/s buses with 3 + 3 + 2 + 2 IDX-like drives. Every 1 ms:
one LRW, the TxPDO parsed, RPDO1 (controlword + target) per axis and a SYNC per bus written into
the RxPDO (N = 3), each drive answering TPDO1 on SYNC. The startup (NMT, CSP mapping by SDO through
the gateway, enable) is not timed. Also printed: WKC errors, parse errors, master_period, and the
position error of every axis after the move. ``GL_BENCH_SECONDS`` sets the simulated seconds.

Then the same ten axes over a veth pair with pysoem (root): ``gatewaylab ecan cia402 -i`` in a
test-made network namespace, 1 kHz for 10,000 cycles (``GL_BENCH_WIRE_CYCLES``), the emulator
(ECAN-Lite, buses, drives) in this process on the real-time clock: WKC errors, parse errors, late
cycles (master_period > 1.5 cycles), the period statistics and the axes at their targets.

Printed, not asserted.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.nmt import NmtCommand
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.ethercat.wire_netns import net_unavailable, veth_namespace
from gatewaylab.hosts.ecanlite.adapter import AdapterConfig, EcanAdapter
from gatewaylab.hosts.ecanlite.cia402 import Cia402
from gatewaylab.hosts.ecanlite.demo import rig_axes, rig_toml
from gatewaylab.hosts.ecanlite.port import ChannelConfig, McanPort, PortConfig
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
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


def wire_run(cycles: int, step: int = 20) -> dict[str, Any] | str:
    """The ten axes over veth with pysoem: the report of ``gatewaylab ecan cia402 --json``, or why
    the run was skipped."""
    skip = net_unavailable("pysoem")
    if skip:
        return skip
    from gatewaylab.common.clock import RealTimeClock
    from gatewaylab.devices.ecanlite.device import EcanLiteDevice
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.ethercat.wire import WireTransport

    with veth_namespace("gl-bhost-", "glh") as (ns, emu, mst):
        clock = RealTimeClock()
        buses = [VirtualBus(clock, f"can{k}", 1_000_000) for k in range(len(LAYOUT))]
        drives = [Drive(clock, bus, n, 0x1000 + n, store_path=None)
                  for bus, nodes in zip(buses, LAYOUT, strict=True) for n in nodes]
        with tempfile.TemporaryDirectory() as tmp:
            device = EcanLiteDevice(clock, [b.attach(f"ecan.mcan{k}") for k, b in enumerate(buses)],
                                    flash_path=Path(tmp) / "ecan.flash")
            for d in drives:
                clock.call_soon(d.start)
            wire = WireTransport(Segment([device.slave]), emu, clock, drive_clock=True, cpu=1)
            wire.start()
            try:
                axes = ",".join(f"0:{ch}:{n}" for ch, nodes in enumerate(LAYOUT) for n in nodes)
                proc = subprocess.run(
                    ["ip", "netns", "exec", ns, sys.executable, "-m", "gatewaylab", "ecan", "cia402", "-i", mst,
                     "--axes", axes, "--pdo-n", "3", "--cycle-us", "1000", "--cycles", str(cycles),
                     "--step", str(step), "--settle-s", "3", "--sdo-timeout", "3", "--json", "--no-progress"],
                    capture_output=True, text=True, timeout=cycles / 1000 * 10 + 300, check=False)
            finally:
                wire.stop()
    if not proc.stdout.strip():
        return f"the master failed (exit {proc.returncode}): {proc.stderr.strip()[-500:]}"
    report: dict[str, Any] = json.loads(proc.stdout)
    report["emulator_errors"] = len(wire.errors)
    return report


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
    cycles = int(os.environ.get("GL_BENCH_WIRE_CYCLES", "10000"))
    w = wire_run(cycles)
    if isinstance(w, str):
        print(f"  over veth with pysoem: skipped: {w}")
        return
    p, e = w["master_period"], w["errors"]
    reached = sum(a["reached"] for a in w["axes"])
    print(f"  over veth with pysoem, {cycles} cycles at 1 kHz: WKC errors {e['wkc_errors']}, parse errors "
          f"{e['parse_errors']}, late cycles {p['late']} (period > 1.5 ms), lost TxPDO images {e['lost_images']}")
    print(f"    master_period mean {p['mean_us']:.1f} us, p99 {p['p99_us']:.1f} us, max {p['max_us']:.1f} us; "
          f"axes at target {reached}/{len(w['axes'])}, emulator errors {w['emulator_errors']}")


if __name__ == "__main__":
    main()
