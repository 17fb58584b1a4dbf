"""Bring CiA 402 servo drives on an EtherCAT line to Operation Enabled and move them (pysoem).

The short program a master-software engineer copies: bring-up (INIT -> PREOP -> SAFEOP -> OP with
the drives' default PDO assignment, ETG.6010 RxPDO 0x1600 / TxPDO 0x1A00), enable (controlword
0x06, 0x07, 0x0F), a move in cyclic synchronous position mode (a ramp of targets every 1 ms),
stop (controlword 0x06 'shutdown', back to SAFEOP, close).

    python examples/soem_cia402.py IFACE [--distance INC] [--time S]

Against the emulator: a rig with ``[[device]] kind = "ethercat_drive"`` and ``[ethercat]
interface = "gl-ecat"``, then ``python examples/soem_cia402.py gl-ecat-m`` (docs/devices/ethercat_drive.md).
"""

from __future__ import annotations

import argparse
import struct
import sys
import time
from typing import Any

import pysoem

RXPDO = struct.Struct("<HiihB")    # 0x1600: controlword, target position, target velocity, target torque, mode
TXPDO = struct.Struct("<HiihbH")   # 0x1A00: statusword, position, velocity, torque, mode display, error code
CSP = 8
PERIOD = 0.001
RX_TIMEOUT_US = 20_000             # generous: a late frame counts as lost


def wait_until(deadline: float) -> None:
    """Spin to the next cycle (a real-time loop would use clock_nanosleep on an isolated core)."""
    while time.perf_counter() < deadline:
        pass


class Line:
    """The master, its drives and one process data cycle."""

    def __init__(self, iface: str) -> None:
        self.master = pysoem.Master()
        self.master.open(iface)
        if self.master.config_init() <= 0:
            raise SystemExit(f"no EtherCAT slaves on {iface}")
        self.drives = [s for s in self.master.slaves
                       if int.from_bytes(s.sdo_read(0x1000, 0), "little") & 0xFFFF == 402]
        if not self.drives:
            raise SystemExit("no CiA 402 drive on the line")
        self.wkc_errors = 0

    def cycle(self) -> None:
        self.master.send_processdata()
        if self.master.receive_processdata(RX_TIMEOUT_US) != self.master.expected_wkc:
            self.wkc_errors += 1

    def command(self, drive: Any, controlword: int, target: int) -> None:
        drive.output = RXPDO.pack(controlword, target, 0, 0, CSP) + bytes(len(drive.output) - RXPDO.size)

    def status(self, drive: Any) -> tuple[int, int, int]:
        statusword, position, _v, _t, _mode, error = TXPDO.unpack(bytes(drive.input)[:TXPDO.size])
        return statusword, position, error

    def bring_up(self) -> None:
        """PREOP -> SAFEOP (config_map reads each drive's PDO assignment by CoE) -> OP."""
        m = self.master
        m.config_map()
        if m.state_check(pysoem.SAFEOP_STATE, 50_000) != pysoem.SAFEOP_STATE:
            raise SystemExit("drives did not reach SAFEOP")
        for drive in self.drives:
            self.command(drive, 0x00, 0)
        m.state = pysoem.OP_STATE
        m.write_state()
        for _ in range(200):
            self.cycle()
            if m.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                return
        raise SystemExit("drives did not reach OP")

    def enable(self) -> list[int]:
        """Shutdown, switch on, enable operation (CiA 402 transitions 2, 3, 4), holding the position."""
        starts = [self.status(d)[1] for d in self.drives]
        for controlword, expected in ((0x06, 0x21), (0x07, 0x23), (0x0F, 0x27)):
            for _ in range(100):
                for drive, x in zip(self.drives, starts, strict=True):
                    self.command(drive, controlword, x)
                self.cycle()
                if all(self.status(d)[0] & 0x6F == expected for d in self.drives):
                    break
            else:
                raise SystemExit(f"statusword {[hex(self.status(d)[0]) for d in self.drives]} after {controlword:#x}")
        return starts

    def move(self, starts: list[int], distance: int, seconds: float) -> None:
        """CSP: a new target every cycle along a straight ramp, then hold it until the axes arrive."""
        steps = round(seconds / PERIOD)
        deadline = time.perf_counter()
        for i in range(1, steps + 200):
            for drive, x in zip(self.drives, starts, strict=True):
                self.command(drive, 0x0F, x + distance * min(i, steps) // steps)
            self.cycle()
            for drive in self.drives:
                statusword, _x, error = self.status(drive)
                if statusword & 0x08:
                    raise SystemExit(f"{drive.name}: fault {error:#06x}")
            deadline += PERIOD
            wait_until(deadline)

    def stop(self) -> None:
        """Shutdown (power stage off), SAFEOP, close."""
        for drive in self.drives:
            self.command(drive, 0x06, self.status(drive)[1])
        for _ in range(10):
            self.cycle()
        self.master.state = pysoem.SAFEOP_STATE
        self.master.write_state()
        self.master.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("iface", help="the network interface of the EtherCAT line")
    parser.add_argument("--distance", type=int, default=40_960, help="increments to move (default 10 turns)")
    parser.add_argument("--time", type=float, default=1.0, help="seconds the move takes")
    args = parser.parse_args(argv)
    line = Line(args.iface)
    print(f"{len(line.drives)} CiA 402 drive(s): {', '.join(d.name for d in line.drives)}")
    line.bring_up()
    starts = line.enable()
    print("Operation enabled:", ", ".join(f"{d.name} at {x}" for d, x in zip(line.drives, starts, strict=True)))
    line.move(starts, args.distance, args.time)
    ends = [line.status(d)[1] for d in line.drives]
    print("moved:", ", ".join(f"{d.name} to {x}" for d, x in zip(line.drives, ends, strict=True)))
    line.stop()
    print(f"stopped; {line.wkc_errors} wrong working counters")
    return 0


if __name__ == "__main__":
    sys.exit(main())
