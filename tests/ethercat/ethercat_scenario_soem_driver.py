"""pysoem master (in the test's network namespace) against a rig whose scenario unplugs a slave while the
master runs its cycle; prints one JSON result. The master is SOEM's simple_test: process data every 2 ms,
and when the working counter is low, the state check and recovery of simple_test's ``ecatcheck`` (a lost
slave is recovered, a slave found in INIT is reconfigured, SAFEOP goes to OP), until the counter is full
again for a while.

Usage: python ethercat_scenario_soem_driver.py INTERFACE SECONDS
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import pysoem

CYCLE_S = 0.002
#: simple_test's EC_TIMEOUTMON (us): the recovery's timeouts
TIMEOUT_MON = 500
#: full working counters in a row that end the run once the fault was seen
FULL_AT_END = 200


def _to_op(master: Any) -> int:
    master.state = pysoem.OP_STATE
    master.write_state()
    for _ in range(400):
        master.send_processdata()
        master.receive_processdata(2000)
        if master.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            return pysoem.OP_STATE
    return int(master.state_check(pysoem.OP_STATE, 5000))


def _check(master: Any, lost: set[int], log: list[str]) -> None:
    """simple_test ``ecatcheck`` for every slave not in OP."""
    master.read_state()
    for i, s in enumerate(master.slaves):
        if s.state != pysoem.OP_STATE:
            if s.state == pysoem.SAFEOP_STATE + pysoem.STATE_ERROR:
                s.state = pysoem.SAFEOP_STATE + pysoem.STATE_ACK
                s.write_state()
                log.append(f"{i}: ack")
            elif s.state == pysoem.SAFEOP_STATE:
                s.state = pysoem.OP_STATE
                s.write_state()
                log.append(f"{i}: SAFEOP -> OP")
            elif s.state > pysoem.NONE_STATE:
                if s.reconfig(TIMEOUT_MON):
                    lost.discard(i)
                    log.append(f"{i}: reconfigured")
            elif i not in lost:
                s.state_check(pysoem.OP_STATE, 2000)
                if s.state == pysoem.NONE_STATE:
                    lost.add(i)
                    log.append(f"{i}: lost")
        if i in lost and s.state == pysoem.NONE_STATE and s.recover(TIMEOUT_MON):
            lost.discard(i)
            log.append(f"{i}: recovered")


def main(iface: str, seconds: float) -> dict[str, Any]:
    master = pysoem.Master()
    master.open(iface)
    out: dict[str, Any] = {"count": master.config_init()}
    for s in master.slaves:
        s.set_watchdog("processdata", 5000)   # a stall of this shared VM must not drop a slave to SAFEOP
    master.config_map()
    out["expected_wkc"] = master.expected_wkc
    out["safeop"] = int(master.state_check(pysoem.SAFEOP_STATE, 50_000))
    out["op"] = _to_op(master)
    wkcs: list[int] = []
    lost: set[int] = set()
    log: list[str] = []
    full_run = 0
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        master.send_processdata()
        wkc = master.receive_processdata(2000)
        wkcs.append(wkc)
        if wkc == master.expected_wkc:
            full_run += 1
            if full_run >= FULL_AT_END and any(0 <= w < master.expected_wkc for w in wkcs):
                break
        else:
            full_run = 0
            if wkc >= 0:              # a reply with a low counter: look at the slaves (a lost frame: wait)
                _check(master, lost, log)
        time.sleep(CYCLE_S)
    out["wkcs"] = wkcs
    out["recovery"] = log
    master.close()
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], float(sys.argv[2]))))
