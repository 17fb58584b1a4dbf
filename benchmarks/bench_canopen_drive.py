"""Simulated seconds per wall second: 8 IDX-like drives in CSP, SYNC + RPDO/TPDO at 1 kHz.

Target: >= 15x real time with one bus, pure and compiled side by
side, each in its own child process (benchmarks/sides.py). A sans-I/O master on each bus sends, every 1 ms,
RPDO1 (controlword + target position, transmission type 1) to each drive and then SYNC; each
drive answers TPDO1 (statusword + position actual, type 1) on every SYNC and runs its 1 kHz
control loop. Two layouts:

* one bus with bus timing switched off (``VirtualBus(timing=False)``): 16 PDOs + SYNC per ms do
  not fit on a real 1 Mbit/s bus (about 1.9 ms of bus time), so frames take no time here;
* four 1 Mbit/s buses with two drives each (about 52 % bus load per bus), frame timing on.

Printed, not asserted.
"""

from __future__ import annotations

import math
import struct
import time

from benchmarks.sides import both, compare, quick
from benchmarks.targets import record
from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.nmt import NmtCommand
from gatewaylab.common.clock import Clock, SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive

PERIOD = 0.001
SIM_SECONDS = 2.0
RPDO = struct.Struct("<Hi")


def _prepare(drive: Drive) -> None:
    node = drive.node
    node.write(0x1800, 2, bytes([1]))          # TPDO1 synchronous, every SYNC
    node.write(0x1400, 2, bytes([1]))          # RPDO1 applied at the next SYNC
    node.write(0x6060, 0, bytes([8]))          # CSP
    for cw in (0x06, 0x07, 0x0F):
        node.write(0x6040, 0, struct.pack("<H", cw))
    node.nmt_command(NmtCommand.START_REMOTE_NODE)


def drive_groups(clock: Clock, buses: int, per_bus: int, timing: bool = True) -> list[tuple[VirtualBus, list[Drive]]]:
    """``buses`` buses with ``per_bus`` started drives each (node ids 1.. over all buses)."""
    out: list[tuple[VirtualBus, list[Drive]]] = []
    for b in range(buses):
        bus = VirtualBus(clock, f"can{b}", timing=timing)
        group = []
        for i in range(per_bus):
            node_id = 1 + b * per_bus + i
            d = Drive(clock, bus, node_id, 0x1000 + node_id)
            d.start()
            group.append(d)
        out.append((bus, group))
    return out


def _layout(buses: int, per_bus: int, timing: bool, control: bool = True) -> tuple[float, int, int]:
    clock = SimulatedClock()
    received = [0]
    drives: list[Drive] = []
    masters = []
    for b, (bus, group) in enumerate(drive_groups(clock, buses, per_bus, timing)):
        drives += group

        def on_tpdo(frame: CanFrame, t: float) -> None:
            received[0] += 1

        # the master's acceptance filter takes the TPDO1 COB-IDs 0x181..0x1FF (standard frames)
        # only, as a master's CAN controller would: the bus calls it for those frames alone
        master = bus.attach(f"master{b}")
        master.rx_table = {cob_id: on_tpdo for cob_id in range(0x181, 0x200)}
        masters.append((master, group))
    clock.advance(0.01)
    for d in drives:
        _prepare(d)
        timer = getattr(d, "_timer", None)     # the drive's 1 kHz control loop (no public handle)
        if not control and timer is not None:   # stack + bus only: no 1 kHz control loop
            timer.cancel()
    start = clock.now()

    # the master's side: per drive its RPDO1 COB-ID and amplitude factor, computed once
    plan = [(master, [(0x200 + d.node.node_id, 1 + d.serial % 3) for d in group])  # type: ignore[operator]
            for master, group in masters]
    sync = CanFrame(0x80, b"")
    pack = RPDO.pack

    def cycle() -> None:
        t = clock.now() - start
        amplitude = 10_000 * (1.0 - math.cos(2 * math.pi * t))
        # the RPDO1 data of each amplitude factor (1..3), packed once per cycle: drives with the
        # same factor get the same set-point
        data = (b"", pack(0x0F, round(amplitude)), pack(0x0F, round(amplitude * 2)),
                pack(0x0F, round(amplitude * 3)))
        for master, group in plan:
            send = master.send
            for cob_id, factor in group:
                send(CanFrame(cob_id, data[factor]))
            send(sync)

    clock.call_every(PERIOD, cycle, first=0.0)
    wall0 = time.perf_counter()
    clock.run_until(start + SIM_SECONDS)
    wall = time.perf_counter() - wall0
    faults = sum(d.faults for d in drives)
    return SIM_SECONDS / wall, received[0], faults


def measure() -> dict[str, float]:
    """Both layouts printed; real-time factors (best of the runs) of each."""
    global SIM_SECONDS
    runs, bare_runs = 3, 2
    if quick():
        SIM_SECONDS, runs, bare_runs = 0.5, 1, 1
    out: dict[str, float] = {}
    for key, label, buses, per_bus, timing in (("one_bus", "1 bus, 8 drives, no frame timing", 1, 8, False),
                                                ("four_buses", "4 buses x 2 drives, 1 Mbit/s timing", 4, 2, True)):
        factor, tpdos, faults = max(_layout(buses, per_bus, timing) for _ in range(runs))
        bare = max(_layout(buses, per_bus, timing, control=False)[0] for _ in range(bare_runs))
        expected = int(SIM_SECONDS / PERIOD) * buses * per_bus
        print(f"CSP 8 drives @ 1 kHz SYNC/RPDO/TPDO, {label}: {factor:.2f}x real time "
              f"(target >= 15x; best of {runs}); TPDOs {tpdos}/{expected}, drive faults {faults}; "
              f"same traffic without the drives' control loop: {bare:.2f}x "
              f"(control loop share of the wall time: {1 - factor / bare:.0%})")
        out[key], out[f"{key}_bare"], out[f"{key}_faults"] = factor, bare, faults
    return out


def targets() -> None:
    """Both layouts in a pure and a default child side by side; records the 8-drive target (one bus)."""
    sides = compare("bench_canopen_drive", "8 CSP drives at 1 kHz, simulated s per wall s (real time = 1)", [
        ("1 bus, no frame timing", "one_bus", ".2f"),
        ("1 bus, without the control loops", "one_bus_bare", ".2f"),
        ("4 buses x 2 drives, 1 Mbit/s timing", "four_buses", ".2f")])
    d = sides[1].result
    record("drives", both(sides, "one_bus", ".1f", "x real time"), d["one_bus"] >= 15 and not d["one_bus_faults"])


def main() -> None:
    targets()


if __name__ == "__main__":
    main()
