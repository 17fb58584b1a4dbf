"""pysoem master for the distributed-clock fault tests, run inside the test's network namespace.

Usage: python ethercat_dc_faults_driver.py INTERFACE. One JSON command per line on stdin, one JSON answer per
line on stdout, so the test injects faults (``gatewaylab fault``) between steps of one master session; between
commands (once in OP) the master keeps cycling every millisecond, as a master's cyclic task does (the slaves'
SM watchdogs would end OP otherwise), and counts what those cycles saw into the next ``watch``:

``init``: open, config_init, config_map, config_dc (SOEM ecx_configdc: receive-time latches, offsets 0x0920,
delays 0x0928) and OP, the delays SOEM measured; ``watch`` N: N cycles about 1 ms apart, each
``send_processdata`` (SOEM adds the FRMW of 0x0910 from the reference clock: drift compensation) and
``receive_processdata``, then 0x092C of every slave (FPRD): the differences of the last cycle, the largest
of the last quarter, lost cycles and reads, wrong working counters, and at the end 0x0932 (the speed
correction); ``config_dc``: DC set up again.
"""

from __future__ import annotations

import json
import select
import sys
import time
from typing import Any

import pysoem

RX_TIMEOUT_US = 100_000


def _signed(raw: bytes) -> int:
    value = int.from_bytes(raw, "little")
    return -(value & 0x7FFFFFFF) if value & 0x80000000 else value


class Driver:
    def __init__(self, iface: str) -> None:
        self.iface = iface
        self.master = pysoem.Master()
        self.cycling = False
        self.idle_lost = self.idle_bad = self.idle_cycles = 0

    def idle_cycle(self) -> None:
        """One cycle between commands."""
        m = self.master
        self.idle_cycles += 1
        m.send_processdata()
        wkc = m.receive_processdata(RX_TIMEOUT_US)
        if wkc <= 0:
            self.idle_lost += 1
        elif wkc != m.expected_wkc:
            self.idle_bad += 1

    def init(self, cmd: dict[str, Any]) -> dict[str, Any]:
        m = self.master
        m.open(self.iface)
        n = m.config_init()
        for s in m.slaves:      # a long SM watchdog: a stall of this shared VM must not end OP (not DC's business)
            s.set_watchdog("processdata", min(2000.0, s.get_max_watchdog_time()))
        m.config_map()
        dc = m.config_dc()
        m.state_check(pysoem.SAFEOP_STATE, 50_000)
        m.state = pysoem.OP_STATE
        m.send_processdata()
        m.receive_processdata(RX_TIMEOUT_US)
        m.write_state()
        state = pysoem.NONE_STATE
        for _ in range(400):
            m.send_processdata()
            m.receive_processdata(RX_TIMEOUT_US)
            state = m.state_check(pysoem.OP_STATE, 5000)
            if state == pysoem.OP_STATE:
                break
        delays = [int.from_bytes(s._fprd(0x0928, 4, RX_TIMEOUT_US), "little") for s in m.slaves]
        self.cycling = state == pysoem.OP_STATE
        return {"count": n, "dc": dc, "op": state, "delays": delays}

    def config_dc(self, cmd: dict[str, Any]) -> dict[str, Any]:
        return {"dc": self.master.config_dc()}

    def watch(self, cmd: dict[str, Any]) -> dict[str, Any]:
        m = self.master
        cycles = int(cmd["n"])
        lost = bad_wkc = lost_reads = 0
        last: list[int | None] = [None] * len(m.slaves)
        tail: list[int] = [0] * len(m.slaves)
        for i in range(cycles):
            m.send_processdata()
            wkc = m.receive_processdata(RX_TIMEOUT_US)
            if wkc <= 0:
                lost += 1
            elif wkc != m.expected_wkc:
                bad_wkc += 1
            for k, s in enumerate(m.slaves):
                try:
                    diff = _signed(s._fprd(0x092C, 4, RX_TIMEOUT_US))
                except pysoem.WkcError:
                    lost_reads += 1
                    continue
                last[k] = diff
                if i >= cycles * 3 // 4:
                    tail[k] = max(tail[k], abs(diff))
            time.sleep(0.001)
        speed: list[int | None] = []
        for s in m.slaves:       # 0x0932: the loop's speed correction (two's complement)
            try:
                speed.append(int.from_bytes(s._fprd(0x0932, 2, RX_TIMEOUT_US), "little", signed=True))
            except pysoem.WkcError:
                speed.append(None)
        out = {"speed": speed, "cycles": cycles, "lost": lost, "bad_wkc": bad_wkc, "lost_reads": lost_reads,
               "last": last, "tail_max": tail, "dc_time": m.dc_time, "idle_cycles": self.idle_cycles,
               "idle_lost": self.idle_lost, "idle_bad_wkc": self.idle_bad}
        self.idle_lost = self.idle_bad = self.idle_cycles = 0
        return out


def main() -> None:
    driver = Driver(sys.argv[1])
    while True:
        if driver.cycling and not select.select([sys.stdin], [], [], 0.001)[0]:
            driver.idle_cycle()
            continue
        line = sys.stdin.readline()
        if not line:
            break
        cmd = json.loads(line)
        what = cmd["do"]
        if what == "quit":
            break
        try:
            answer = getattr(driver, what)(cmd)
        except Exception as exc:  # the test prints it
            answer = {"failed": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(answer), flush=True)
    driver.master.close()


if __name__ == "__main__":
    main()
