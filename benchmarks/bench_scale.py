"""Scale in real time: a plant of 8 buses x 8 IDX-like drives (64 drives) at 1 Mbit/s and about
50 % bus load, in one rig, and the same plant split over two rigs joined by cannelloni tunnels.

A master on each bus (a controller in this process's rig) sends, every 4 ms, RPDO1 (controlword +
target position) to its 8 drives and SYNC; each drive answers TPDO1 (type 1) on every SYNC: 17 frames
of about 111-135 us per 4 ms, about 50 % of a 1 Mbit/s bus. Printed per layout: TPDOs missing (not
received 2 s after the end) and master frames still queued then, late TPDOs (received more than one
cycle after their SYNC), late cycles (the master's timer ran more than half a cycle late), bus load,
and CPU (percent of one core, both processes for the split). SCALE_SECONDS sets the measured span
(default 60). Real time: the figures are those of the machine it runs on, a loaded one (other
processes wanting the CPUs) shows late cycles and a lower load whatever gatewaylab does.

Split: rig A (this process: the masters, drives 1-4 of every bus) and rig B (`gatewaylab run`: drives
5-8 of every bus), each bus joined by its own tunnel on 127.0.0.1. The drives' control loops run every
4 ms (``control_period``). Printed, not asserted.
"""

from __future__ import annotations

import os
import struct
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gatewaylab.bus import CanFrame
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.process import RigProcess, free_udp_ports, rig_toml
from gatewaylab.rig.runtime import Rig

SECONDS = float(os.environ.get("SCALE_SECONDS", "60"))
BUSES, PER_BUS, PERIOD = 8, 8, 0.004
#: the drives' control loop runs once per SYNC period (its CSP interpolation cycle): 64 drives at the
#: default 1 kHz need more than one core of Python (bench_canopen_drive: about 0.1 ms per drive tick)
CONTROL = PERIOD
SETTLE = 1.0
RPDO = struct.Struct("<Hi")


def plant(drives: Callable[[int], range], tunnels: list[tuple[str, str]] | None = None) -> dict[str, Any]:
    """A rig dict: BUSES buses, the drives ``drives(bus)`` (positions 0..7) on each, optional tunnels."""
    data: dict[str, Any] = {"clock": "realtime",
                            "bus": [{"name": f"can{b}", "endpoint": "none"} for b in range(BUSES)],
                            "drive": [{"bus": f"can{b}", "node_id": 1 + i, "serial": 0x10000 + 16 * b + i,
                                       "name": f"b{b}n{1 + i}", "control_period": CONTROL}
                                      for b in range(BUSES) for i in drives(b)]}
    if tunnels:
        data["tunnel"] = [{"kind": "cannelloni", "bus": f"can{b}", "local": local, "remote": remote,
                           "timeout_us": 200} for b, (local, remote) in enumerate(tunnels)]
    return data


def sdo_write(node_id: int, index: int, sub: int, value: int, size: int) -> CanFrame:
    """A CiA 301 expedited SDO download request (command 0x23/0x27/0x2B/0x2F by size)."""
    command = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    return CanFrame(0x600 + node_id, bytes([command, index & 0xFF, index >> 8, sub])
                    + value.to_bytes(size, "little").ljust(4, b"\0"))


class Masters:
    """The masters of every bus of ``rig`` and what they count."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.clock = rig.clock
        self.tpdos = 0
        self.late_tpdos = 0
        self.cycles = 0
        self.late_cycles = 0
        self.cycle_at = 0.0
        self.counting = False
        self.masters = [rig.buses[f"can{b}"].attach(f"master{b}", on_frame=self._on_frame) for b in range(BUSES)]

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        if self.counting and 0x181 <= frame.can_id <= 0x188:
            self.tpdos += 1
            if t - self.cycle_at > PERIOD:
                self.late_tpdos += 1

    def prepare(self) -> None:
        """Every drive (local or behind a tunnel): TPDO1/RPDO1 synchronous, CSP, enabled, operational."""
        for master in self.masters:
            for node in range(1, PER_BUS + 1):
                for index, sub, value, size in ((0x1800, 2, 1, 1), (0x1400, 2, 1, 1), (0x6060, 0, 8, 1),
                                                (0x6040, 0, 6, 2), (0x6040, 0, 7, 2), (0x6040, 0, 0xF, 2)):
                    master.send(sdo_write(node, index, sub, value, size))
            master.send(CanFrame(0x000, bytes([0x01, 0x00])))      # NMT start all nodes

    def start(self, start: float) -> None:
        self.start_at = start
        self.timer = self.clock.call_every(PERIOD, self._cycle, first=start - self.clock.now())

    def _cycle(self) -> None:
        now = self.clock.now()
        self.cycles += 1
        scheduled = self.start_at + (self.cycles - 1) * PERIOD
        if now - scheduled > PERIOD / 2:
            self.late_cycles += 1
        self.cycle_at = now
        target = self.cycles * 10
        frames = [CanFrame(0x200 + n, RPDO.pack(0x0F, target)) for n in range(1, PER_BUS + 1)]
        for master in self.masters:
            for frame in frames:
                master.send(frame)
            master.send(CanFrame(0x80))


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(rig: Rig, other: RigProcess | None = None) -> str:
    masters = Masters(rig)
    rig.start()
    masters.prepare()
    clock = rig.clock
    begin = clock.now() + SETTLE
    masters.start(begin)

    def count() -> None:
        masters.counting = True
        masters.cycles = masters.late_cycles = 0
        masters.start_at = begin + PERIOD              # the first cycle counted
        for bus in rig.buses.values():
            bus.stats.busy_time = 0.0
            bus.stats.since = clock.now()
        state["cpu"] = time.process_time()
        state["other"] = _cpu_seconds(other.pid) if other is not None else 0.0

    state: dict[str, float] = {}
    clock.call_at(begin + PERIOD / 2, count)
    end = begin + SECONDS
    rig.run(until=lambda: clock.now() >= end, signals=False)
    masters.timer.cancel()
    cpu = (time.process_time() - state["cpu"]) / SECONDS
    other_cpu = ((_cpu_seconds(other.pid) - state["other"]) / SECONDS) if other is not None else 0.0
    load = sum(bus.load_percent() for bus in rig.buses.values()) / BUSES
    # what is still queued or in a tunnel is late, not lost: let it arrive (at most 2 s)
    drained = clock.now() + 2.0
    rig.run(until=lambda: clock.now() >= drained, signals=False)
    masters.counting = False
    expected = masters.cycles * BUSES * PER_BUS
    lost = max(0, expected - masters.tpdos)
    unsent = sum(len(m.tx_queue) for m in masters.masters)
    cpu_text = f"CPU {cpu:.0%}" + (f" + {other_cpu:.0%} (rig B)" if other is not None else "") + " of one core"
    return (f"{masters.cycles} cycles, TPDOs {masters.tpdos}/{expected} (missing {lost}; master frames still "
            f"queued 2 s after the end: {unsent}), late TPDOs {masters.late_tpdos}, late cycles "
            f"{masters.late_cycles}, bus load {load:.0f} %, {cpu_text}")


def single() -> str:
    rig = Rig(parse_rig(plant(lambda b: range(PER_BUS))), clock=RealTimeClock())
    try:
        return run(rig)
    finally:
        rig.close()


def split() -> str:
    ports = free_udp_ports(2 * BUSES)
    a_ports, b_ports = ports[:BUSES], ports[BUSES:]
    b_ends = [(f"127.0.0.1:{b_ports[b]}", f"127.0.0.1:{a_ports[b]}") for b in range(BUSES)]
    a_ends = [(remote, local) for local, remote in b_ends]
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as folder:
        b_file = Path(folder) / "b.toml"
        b_file.write_text(rig_toml(plant(lambda b: range(PER_BUS // 2, PER_BUS), b_ends)))
        with RigProcess(b_file, workdir=folder, timeout=120) as other:
            rig = Rig(parse_rig(plant(lambda b: range(PER_BUS // 2), a_ends)), clock=RealTimeClock())
            try:
                return run(rig, other)
            finally:
                rig.close()


def main() -> None:
    print(f"plant of {BUSES} buses x {PER_BUS} drives, SYNC + RPDO/TPDO every {PERIOD * 1e3:.0f} ms, drive control "
          f"loops every {CONTROL * 1e3:.0f} ms, {SECONDS:.0f} s real time each")
    print(f"  one rig:                       {single()}")
    print(f"  split over two rigs (cannelloni): {split()}")


if __name__ == "__main__":
    main()
