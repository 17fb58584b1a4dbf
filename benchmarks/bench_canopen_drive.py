"""Simulated seconds per wall second: 8 IDX-like drives in CSP, SYNC + RPDO/TPDO at 1 kHz.

Issue 3 benchmark (target >= 5x real time). A sans-I/O master on each bus sends, every 1 ms,
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

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.nmt import NmtCommand
from gatewaylab.common.clock import SimulatedClock
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


def _layout(buses: int, per_bus: int, timing: bool, control: bool = True) -> tuple[float, int, int]:
    clock = SimulatedClock()
    received = [0]
    drives: list[Drive] = []
    masters = []
    for b in range(buses):
        bus = VirtualBus(clock, f"can{b}", timing=timing)
        group = []
        for i in range(per_bus):
            node_id = 1 + b * per_bus + i
            d = Drive(clock, bus, node_id, 0x1000 + node_id)
            d.start()
            group.append(d)
        drives += group

        def on_frame(frame: CanFrame, t: float) -> None:
            if 0x181 <= frame.can_id <= 0x1FF:
                received[0] += 1

        master = bus.attach(f"master{b}", on_frame=on_frame)
        masters.append((master, group))
    clock.advance(0.01)
    for d in drives:
        _prepare(d)
        if not control and d._timer is not None:   # stack + bus only: no 1 kHz control loop
            d._timer.cancel()
    start = clock.now()

    # the master's side: per drive its RPDO1 COB-ID and amplitude factor, computed once
    plan = [(master, [(0x200 + d.node.node_id, 1 + d.serial % 3) for d in group])  # type: ignore[operator]
            for master, group in masters]
    sync = CanFrame(0x80, b"")
    pack = RPDO.pack

    def cycle() -> None:
        t = clock.now() - start
        amplitude = 10_000 * (1.0 - math.cos(2 * math.pi * t))
        for master, group in plan:
            send = master.send
            for cob_id, factor in group:
                send(CanFrame(cob_id, pack(0x0F, round(amplitude * factor))))
            send(sync)

    clock.call_every(PERIOD, cycle, first=0.0)
    wall0 = time.perf_counter()
    clock.run_until(start + SIM_SECONDS)
    wall = time.perf_counter() - wall0
    faults = sum(d.faults for d in drives)
    return SIM_SECONDS / wall, received[0], faults


def main() -> None:
    for label, buses, per_bus, timing in (("1 bus, 8 drives, no frame timing", 1, 8, False),
                                           ("4 buses x 2 drives, 1 Mbit/s timing", 4, 2, True)):
        runs = [_layout(buses, per_bus, timing) for _ in range(3)]
        factor, tpdos, faults = max(runs)
        bare = max(_layout(buses, per_bus, timing, control=False)[0] for _ in range(2))
        expected = int(SIM_SECONDS / PERIOD) * buses * per_bus
        print(f"CSP 8 drives @ 1 kHz SYNC/RPDO/TPDO, {label}: {factor:.2f}x real time "
              f"(target >= 5x; best of 3); TPDOs {tpdos}/{expected}, drive faults {faults}; "
              f"same traffic without the drives' control loop: {bare:.2f}x "
              f"(control loop share of the wall time: {1 - factor / bare:.0%})")


if __name__ == "__main__":
    main()
