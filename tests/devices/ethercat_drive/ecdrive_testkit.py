"""Helpers of the ethercat_drive tests: segments of drives on a simulated clock, the in-process
master brought to OP, the default process image layout (ETG.6010 0x1600 / 0x1A00)."""

from __future__ import annotations

import gc
import json
import struct
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import wire_kit

from gatewaylab.common.clock import RealTimeClock, SimulatedClock
from gatewaylab.devices.ethercat_drive import EthercatDrive
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport
from gatewaylab.hosts.ethercat.master import Master

#: Default RxPDO 0x1600: controlword, target position, target velocity, target torque, mode.
RX = struct.Struct("<HiihB")
#: Default TxPDO 0x1A00: statusword, position, velocity, torque, mode display, error code.
TX = struct.Struct("<HiihbH")
CSP, CSV, CST = 8, 9, 10
STATE_MASK = 0x006F


@dataclass
class Line:
    """A simulated segment of drives and the in-process master that scanned it."""

    clock: SimulatedClock
    drives: list[EthercatDrive]
    master: Master

    def outputs(self, pos: int, cw: int, target: int = 0, velocity: int = 0, torque: int = 0,
                mode: int = CSP, axis: int = 0) -> None:
        """The default RxPDO of one axis into the image."""
        self.master.pdo_write(pos, axis * RX.size, RX.pack(cw, target, velocity, torque, mode))

    def inputs(self, pos: int, axis: int = 0) -> tuple[int, int, int, int, int, int]:
        """The default TxPDO of one axis from the image."""
        sw, x, v, t, mode, err = TX.unpack(self.master.pdo_read(pos, axis * TX.size, TX.size))
        return sw, x, v, t, mode, err

    def cycle(self, n: int = 1, period: float = 0.001) -> int:
        """``n`` process data exchanges ``period`` apart; returns the last working counter."""
        wkc = 0
        for _ in range(n):
            wkc = self.master.exchange_process_data()
            self.clock.advance(period)
        return wkc

    def enable(self, pos: int, mode: int = CSP, axis: int = 0, target: int = 0) -> list[int]:
        """Controlword 0x06, 0x07, 0x0F (CiA 402 transitions 2, 3, 4); the statusword after each."""
        seen = []
        for cw in (0x06, 0x07, 0x0F):
            self.outputs(pos, cw, target=target, mode=mode, axis=axis)
            self.cycle(3)
            seen.append(self.inputs(pos, axis)[0])
        return seen


def make_line(n: int = 2, axes: int = 1, *, dc: bool = False, preop_setup: object = None) -> Line:
    """``n`` drives (serial 0x3001..) scanned, mapped with their defaults and brought to OP."""
    clock = SimulatedClock()
    drives = [EthercatDrive(clock, f"GL-Drive #{i}", serial=0x3001 + i, axes=axes) for i in range(n)]
    master = Master(clock, Segment([d.slave for d in drives]))
    master.scan()
    master.set_state(AlState.PREOP)
    if callable(preop_setup):
        preop_setup(master)
    line = Line(clock, drives, master)
    to_op(line, dc=dc)
    return line


def to_op(line: Line, *, dc: bool = False) -> None:
    """config_map, optional DC SYNC0 (1 ms), SAFEOP, a few exchanges, OP."""
    m = line.master
    m.config_map()
    if dc:
        for pos in range(len(line.drives)):
            m.configure_sync0(pos, 0.001, start_delay=0.0005)
    m.set_state(AlState.SAFEOP)
    line.cycle(2)
    m.set_state(AlState.OP)
    line.cycle(2)


def net_capable() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip (tests/wire_kit.py)."""
    return wire_kit.net_capable()


@dataclass(frozen=True)
class DriveVeth:
    """Emulator end in this namespace, master end inside ``namespace``."""

    namespace: str
    emulator_iface: str
    master_iface: str

    def run(self, script: Path, *args: str, timeout: float = 180.0,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """Run a Python script inside the namespace with the master interface as first argument."""
        return subprocess.run(["ip", "netns", "exec", self.namespace, sys.executable, str(script),
                               self.master_iface, *args], capture_output=True, text=True, timeout=timeout,
                              check=False, env=env)


def serve_raw(veth: DriveVeth, script: Path, *args: str, n: int = 2,
              stats: dict[str, int] | None = None) -> tuple[subprocess.CompletedProcess[str], list[EthercatDrive]]:
    """``n`` drives on the emulator end while ``script`` runs as the master in the namespace; the wire's
    counters are added into ``stats`` when given, and the script can read them meanwhile (a KickCAT driver
    judges each rerun by them: tests/ethercat/kickcat_kit.py run_step)."""
    clock = RealTimeClock()
    drives = [EthercatDrive(clock, f"GL-Drive #{i}", serial=0x3001 + i) for i in range(n)]
    wire = WireTransport(Segment([d.slave for d in drives]), veth.emulator_iface, clock, drive_clock=True,
                         realtime=True)
    # The test process holds the whole suite's objects: a full garbage collection of them, which the
    # control periods' allocations trigger now and then, would stall the wire thread for longer than
    # SOEM's 2 ms register timeout. Frozen, they are not scanned (a `gatewaylab run` heap is small).
    gc.collect()
    gc.freeze()
    wire.start()
    try:
        if stats is None:
            proc = veth.run(script, *args)
        else:
            with wire_kit.serve_wire_counters(wire.stats) as env:
                proc = veth.run(script, *args, env=env)
    finally:
        wire.stop()
        gc.unfreeze()
        with clock.lock:
            for d in drives:
                d.stop()
    assert not wire.errors
    if stats is not None:
        for key, value in wire.stats().items():
            stats[key] = stats.get(key, 0) + value
    return proc, drives


def serve(veth: DriveVeth, script: Path, *args: str, n: int = 2) -> tuple[dict[str, Any], list[EthercatDrive]]:
    """:func:`serve_raw` of a driver that prints one JSON result."""
    proc, drives = serve_raw(veth, script, *args, n=n)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), drives
