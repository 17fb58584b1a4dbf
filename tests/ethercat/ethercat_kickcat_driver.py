"""KickCAT master for the ``ethercat_io`` tests (run in a subprocess inside the test's network namespace):
scan, mapping read over CoE, OP, loop-back process data; prints one JSON result.

Usage: python ethercat_kickcat_driver.py INTERFACE CYCLES
"""

from __future__ import annotations

import itertools
import json
import struct
import sys
import time
from typing import Any

import kickcat
from kickcat_kit import MAILBOX_ATTEMPTS, run_as_kickcat_readme_says, run_step

#: KickCAT's defaults (Link.h 2 ms, Bus.h 1 s per SDO); a step that fails on a lost frame runs again
#: (tests/ethercat/kickcat_kit.py run_step), each failure printed with the result under ``retries``
LINK_TIMEOUT_S = 0.002
SDO_TIMEOUT_S = 1.0
OUT = struct.Struct("<Bhh")
IN = struct.Struct("<BhhI")


def scan(iface: str) -> Any:
    """A fresh link and bus, KickCAT's init (INIT -> PREOP)."""
    link = kickcat.create_link(iface, "")
    link.set_timeout(LINK_TIMEOUT_S)
    bus = kickcat.Bus(link)
    bus.init(0.5)           # the slaves' watchdog (not a timeout of the master)
    return bus


def main(iface: str, cycles: int) -> dict[str, Any]:
    run_as_kickcat_readme_says()
    bus, retries = run_step("init", lambda: scan(iface))
    slaves = bus.slaves()
    out: dict[str, Any] = {"count": len(slaves), "retries": retries}

    def sdo(slave: Any, index: int, sub: int, size: int) -> bytes:
        data, failed = run_step(f"read {index:04X}:{sub}", lambda: bytes(
            bus.read_sdo(slave, index, sub, kickcat.Access.PARTIAL, size, SDO_TIMEOUT_S)), attempts=MAILBOX_ATTEMPTS)
        retries.extend(failed)
        return data

    out["names"] = [sdo(s, 0x1008, 0, 32).decode().rstrip("\x00") for s in slaves]
    out["identity"] = [[int.from_bytes(sdo(s, 0x1018, k, 4), "little") for k in (1, 2, 3)] for s in slaves]
    bus.create_mapping(4096)
    out["sizes"] = [[s.output_size, s.input_size] for s in slaves]
    bad = [0, 0]

    def cycle() -> bool:
        try:
            bus.process_data()
        except RuntimeError as exc:
            bad[0 if "INVALID_WKC" in str(exc) else 1] += 1
            return False
        return True

    bus.request_state(kickcat.State.SAFE_OP)
    bus.wait_for_state(kickcat.State.SAFE_OP, 2.0)
    cycle()
    bus.request_state(kickcat.State.OPERATIONAL)
    bus.wait_for_state(kickcat.State.OPERATIONAL, 2.0, cycle)
    out["op"] = [str(bus.get_state(s)) for s in slaves]
    echoed = 0
    counters: list[list[int]] = [[] for _ in slaves]
    for i in range(cycles):
        for k, s in enumerate(slaves):
            s.set_output_bytes(OUT.pack((i + k) & 0xFF, 100 * k - 7, -3))
        time.sleep(0.0005)
        if not cycle():
            continue
        for k, s in enumerate(slaves):
            digital, a1, a2, counter = IN.unpack(bytes(s.input_data)[:IN.size])
            counters[k].append(counter)
            # LRD before LWR: the inputs echo the outputs of the previous good cycle
            if i and (digital, a1, a2) == ((i - 1 + k) & 0xFF, 100 * k - 7, -3):
                echoed += 1
    out["bad_wkc"], out["lost"], out["echoed"] = bad[0], bad[1], echoed
    out["counters_rise"] = [all(b > a for a, b in itertools.pairwise(c)) and len(c) > 1 for c in counters]
    bus.request_state(kickcat.State.INIT)
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], int(sys.argv[2]))))
