"""pysoem master (in the test's network namespace) that pauses longer than the SM watchdog; prints one JSON
result. The scene of a master stalled by its host: every slave falls back to SAFEOP + 0x001B, and the
working counter of the next cycles tells the master so.

Usage: python ethercat_soem_watchdog_driver.py INTERFACE
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import pysoem

#: Correctness, not timing: a frame only counts as lost after 100 ms (the VM is shared and noisy).
RX_TIMEOUT_US = 100_000
WATCHDOG_MS = 100
#: The master's pause: well beyond the watchdog, as a stalled host's.
PAUSE_S = 0.4
CYCLES = 20


def _cycles(master: Any, n: int) -> list[int]:
    """n process data cycles; their working counters (-1: no reply within the timeout, a lost frame)."""
    out = []
    for _ in range(n):
        master.send_processdata()
        out.append(master.receive_processdata(RX_TIMEOUT_US))
    return out


def _to(master: Any, state: int, ack: bool = False) -> int:
    for s in master.slaves:
        s.state = state | (pysoem.STATE_ACK if ack else 0)
        s.write_state()
    reached = pysoem.NONE_STATE
    for _ in range(400):
        _cycles(master, 1)
        reached = master.state_check(state, 5000)
        if reached == state:
            break
    return int(reached)


def main(iface: str) -> dict[str, Any]:
    master = pysoem.Master()
    master.open(iface)
    out: dict[str, Any] = {"count": master.config_init()}
    for s in master.slaves:
        s.set_watchdog("processdata", WATCHDOG_MS)
    master.config_map()
    out["expected_wkc"] = master.expected_wkc
    out["safeop"] = int(master.state_check(pysoem.SAFEOP_STATE, 50_000))
    out["op"] = _to(master, pysoem.OP_STATE)
    time.sleep(PAUSE_S)  # the master stalls (no process data) for longer than the SM watchdog
    stopped = time.monotonic()
    while time.monotonic() - stopped < 5.0:  # the fallback happened during the pause; read it
        master.read_state()
        if all(s.state & 0x10 for s in master.slaves):
            break
    out["after_pause"] = [(s.state, s.al_status) for s in master.slaves]
    out["wkc_after_pause"] = _cycles(master, CYCLES)
    # simple_test's recovery: acknowledge in SAFEOP, then OP (a long watchdog from now on: the VM may stall)
    for s in master.slaves:
        s.set_watchdog("processdata", 5000)
    out["acked"] = _to(master, pysoem.SAFEOP_STATE, ack=True)
    out["wkc_safeop_acked"] = _cycles(master, CYCLES)
    out["recovered"] = _to(master, pysoem.OP_STATE)
    out["wkc_recovered"] = _cycles(master, CYCLES)
    master.close()
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])))
