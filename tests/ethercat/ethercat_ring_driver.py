"""pysoem master for the port and ring tests, run inside the test's namespace; one JSON event per line on stdout.

Usage: python ethercat_ring_driver.py IF_A IF_B|- CYCLES

``IF_B`` given: SOEM's cable redundancy (``Master.open(IF_A, IF_B)`` -> ``ecx_init_redundant``: every frame goes
out on both interfaces, ``ecx_waitinframe_red`` merges what comes back). The master scans, goes to OP and says
``{"ev": "op", ...}``; then, for each line it reads on stdin (a phase name; ``end`` stops), it runs CYCLES process
data cycles (1 ms apart; a name starting with ``recover`` first brings slaves that left OP back, as SOEM's
samples do) and says ``{"ev": "phase", "name": ..., "wkc": {value: count}, "lost": n, "dl": [...]}``
with each slave's DL status 0x0110 (None for a slave that does not answer) and AL state read afterwards, and
``every``: the working counters of every cycle since OP (-1: lost). Between phases it keeps cycling (a master that
stopped would let the slaves' SM watchdogs expire).
"""

from __future__ import annotations

import collections
import json
import select
import sys
import time
from typing import Any

import pysoem

#: Correctness, not timing: default SOEM timeouts for the cycle (EC_TIMEOUTRET, 2 ms), generous for the set-up.
RX_TIMEOUT_US = 2_000
SLOW_US = 3_000_000


def say(**event: Any) -> None:
    print(json.dumps(event), flush=True)


def to_op(master: Any) -> int:
    master.config_map()
    master.state_check(pysoem.SAFEOP_STATE, 50_000)
    master.state = pysoem.OP_STATE
    master.send_processdata()
    master.receive_processdata(RX_TIMEOUT_US)
    master.write_state()
    state = pysoem.NONE_STATE
    for _ in range(400):
        master.send_processdata()
        master.receive_processdata(RX_TIMEOUT_US)
        state = master.state_check(pysoem.OP_STATE, 5_000)
        if state == pysoem.OP_STATE:
            break
    return int(state)


def recover(master: Any) -> None:
    """What SOEM's samples do (red_test's ecatcheck) for slaves that are not in OP: a slave that lost its station
    address (powered on again) is found at its position and given it back (``ecx_recover_slave``), one in INIT or
    PREOP is configured again (``ecx_reconfig_slave``), an error is acknowledged; then OP is requested."""
    master.read_state()
    for slave in master.slaves:
        if slave.state == pysoem.NONE_STATE:
            slave.recover(100_000)
    master.read_state()
    for slave in master.slaves:
        if slave.state in (pysoem.INIT_STATE, pysoem.PREOP_STATE):
            slave.reconfig(100_000)
    master.read_state()
    for slave in master.slaves:
        if slave.state == pysoem.SAFEOP_STATE + pysoem.STATE_ERROR:
            slave.state = pysoem.SAFEOP_STATE + pysoem.STATE_ACK
            slave.write_state()
        if slave.state != pysoem.OP_STATE:
            slave.state = pysoem.OP_STATE
            slave.write_state()
    for _ in range(400):
        master.send_processdata()
        master.receive_processdata(RX_TIMEOUT_US)
        if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
            break


def dl_status(master: Any) -> list[int | None]:
    out: list[int | None] = []
    for slave in master.slaves:
        try:
            out.append(int.from_bytes(slave._fprd(0x0110, 2, 20_000), "little"))
        except pysoem.WkcError:
            out.append(None)
    return out


def main() -> None:
    if_a, if_b, cycles = sys.argv[1], sys.argv[2], int(sys.argv[3])
    master = pysoem.Master()
    master.sdo_read_timeout = SLOW_US
    master.sdo_write_timeout = SLOW_US
    master.open(if_a, None if if_b == "-" else if_b)
    count = master.config_init()
    for slave in master.slaves:     # a long SM watchdog: a stall of this shared VM must not leave OP
        slave.set_watchdog("processdata", 1000)
    op = to_op(master)
    say(ev="op", count=count, op=op, expected_wkc=master.expected_wkc, dl=dl_status(master),
        names=[s.name for s in master.slaves])
    phase = ""      # the phase being measured ("": none; the master cycles on between phases)
    wkcs: collections.Counter[int] = collections.Counter()
    lost = done = 0
    every: collections.Counter[int] = collections.Counter()    # every cycle since OP (-1: lost), phases or not
    while True:
        master.send_processdata()
        wkc = master.receive_processdata(RX_TIMEOUT_US)
        every[max(wkc, -1)] += 1
        if phase:
            done += 1
            if wkc <= 0:
                lost += 1
            else:
                wkcs[wkc] += 1
            if done == cycles:
                master.read_state()
                say(ev="phase", name=phase, wkc={str(k): v for k, v in sorted(wkcs.items())}, lost=lost,
                    cycles=cycles, dl=dl_status(master), states=[s.state for s in master.slaves],
                    every={str(k): v for k, v in sorted(every.items())})
                phase = ""
        elif select.select([sys.stdin], [], [], 0)[0]:
            phase = sys.stdin.readline().strip()
            if phase in ("end", ""):
                break
            if phase.startswith("recover"):
                recover(master)
            wkcs.clear()
            lost = done = 0
        time.sleep(0.001)
    master.state = pysoem.INIT_STATE
    master.write_state()
    master.close()
    say(ev="end")


if __name__ == "__main__":
    main()
