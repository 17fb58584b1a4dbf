"""A pysoem (SOEM) master with SOEM's default timeouts cycling one ``ethercat_io`` at 1 kHz, that counts per phase
what it sees while the test injects EtherCAT line faults into the rig (run inside the test's namespace).

stdin lines: ``mark NAME`` starts phase NAME (the cycles before it belong to the previous one), ``recover``
takes the slave back to OP the way SOEM's simple_test does (an AL error acknowledged, SAFEOP -> OP) while
cycling, ``end`` stops. Prints ``{"ev": "op", "expected": WKC}`` once in OP, ``{"ev": "marked", "name": ...}``
after each mark, ``{"ev": "recovered", "state": ...}`` and at the end ``{"ev": "done", "phases": {NAME:
{"cycles", "lost", "wkc": {value: cycles}}}}``: a cycle is lost when ``receive_processdata`` gives <= 0
(no reply within EC_TIMEOUTRET, 2 ms).

Usage: python ethercat_line_fault_master.py INTERFACE WATCHDOG-MS (the slave's process data watchdog: long
enough that a stall of this loaded machine does not end OP by itself, short enough for a link-down to)
"""

from __future__ import annotations

import json
import select
import sys
import time
from typing import Any

import pysoem

PERIOD = 0.001
STATE_ERROR_ACK = 0x10


def emit(event: str, **fields: Any) -> None:
    print(json.dumps({"ev": event, **fields}), flush=True)


def to_op(m: Any, watchdog_ms: int) -> None:
    """SOEM's simple_test bring-up with its default timeouts: scan, map, SAFEOP, OP with process data."""
    if m.config_init() != 1:
        raise RuntimeError("SOEM found no slave or more than one")
    m.slaves[0].set_watchdog("processdata", watchdog_ms)
    m.config_map()
    if m.state_check(pysoem.SAFEOP_STATE, 50_000) != pysoem.SAFEOP_STATE:
        raise RuntimeError("SAFEOP not reached")
    m.state = pysoem.OP_STATE
    m.send_processdata()
    m.receive_processdata()
    m.write_state()
    for _ in range(400):
        m.send_processdata()
        m.receive_processdata()
        if m.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            return
    raise RuntimeError("OP not reached")


def recover(m: Any) -> str:
    """simple_test's ecatcheck for one slave: acknowledge SAFEOP + error, then request OP, cycling meanwhile."""
    slave = m.slaves[0]
    for _ in range(2000):
        m.send_processdata()
        m.receive_processdata()
        m.read_state()
        if slave.state == pysoem.OP_STATE:
            return "OP"
        if slave.state == pysoem.SAFEOP_STATE + STATE_ERROR_ACK:
            slave.state = pysoem.SAFEOP_STATE + STATE_ERROR_ACK
            slave.write_state()
        elif slave.state == pysoem.SAFEOP_STATE:
            slave.state = pysoem.OP_STATE
            slave.write_state()
        time.sleep(PERIOD)
    return f"0x{slave.state:02X}"


def main(iface: str, watchdog_ms: int) -> dict[str, Any]:
    m = pysoem.Master()
    m.open(iface)
    to_op(m, watchdog_ms)
    emit("op", expected=m.expected_wkc)
    phases: dict[str, dict[str, Any]] = {}
    phase = phases["start"] = {"cycles": 0, "lost": 0, "wkc": {}}
    t_next = time.perf_counter()
    while True:
        m.send_processdata()
        wkc = m.receive_processdata()           # SOEM's default: EC_TIMEOUTRET, 2000 us
        phase["cycles"] += 1
        if wkc <= 0:
            phase["lost"] += 1
        else:
            phase["wkc"][str(wkc)] = phase["wkc"].get(str(wkc), 0) + 1
        if select.select([sys.stdin], [], [], 0)[0]:
            words = sys.stdin.readline().split()
            if not words or words[0] == "end":
                break
            if words[0] == "mark":
                phase = phases[words[1]] = {"cycles": 0, "lost": 0, "wkc": {}}
                emit("marked", name=words[1])
            elif words[0] == "recover":
                emit("recovered", state=recover(m))
        t_next += PERIOD
        slack = t_next - time.perf_counter()
        if slack > 0:
            time.sleep(slack)
        else:
            t_next = time.perf_counter()
    m.state = pysoem.INIT_STATE
    m.write_state()
    m.close()
    return phases


if __name__ == "__main__":
    emit("done", phases=main(sys.argv[1], int(sys.argv[2])))
