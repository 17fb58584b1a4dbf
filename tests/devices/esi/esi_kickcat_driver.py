"""KickCAT master against a rig of ESI-built slaves (run in the test's network namespace); prints one JSON result.

Usage: python esi_kickcat_driver.py INTERFACE CYCLES

KickCAT as its README runs it: the process at SCHED_FIFO priority 3 (when allowed), its default timeouts (link
2 ms, ``bus.init(0.1)``), no retries. Scan, mapping (read over CoE where the slave has it, else from SII),
SAFEOP, OP, then CYCLES process data cycles: slave 0 is an EL2008, slave 1 an EL1859 whose inputs echo
its outputs (behaviour rules; KickCAT reads the inputs (LRD) before it writes the outputs (LWR), so a
cycle's inputs echo the previous cycle's outputs), slave 2 an EL1008, slave 3 the ESI copy of
``ethercat_io``. A cycle that raises a timeout is lost (counted); a wrong working counter is counted apart.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import kickcat
from kickcat_kit import run_as_kickcat_readme_says, run_step


def scan(iface: str) -> Any:
    """KickCAT's defaults (2 ms link timeout): a fresh link and bus, init and mapping."""
    link = kickcat.create_link(iface, "")
    bus = kickcat.Bus(link)
    bus.init(0.1)
    bus.create_mapping(4096)
    return bus


def main(iface: str, cycles: int) -> dict[str, Any]:
    run_as_kickcat_readme_says()
    # a scan that lost a frame runs again, every failure printed with the result (kickcat_kit.run_step)
    bus, retries = run_step("scan", lambda: scan(iface))
    slaves = bus.slaves()
    out: dict[str, Any] = {"count": len(slaves), "retries": retries}
    out["sizes"] = [[s.output_size, s.input_size] for s in slaves]
    bad = {"wkc": 0, "lost": 0}

    def cycle() -> bool:
        try:
            bus.process_data()
        except RuntimeError as exc:
            bad["wkc" if "INVALID_WKC" in str(exc) else "lost"] += 1
            return False
        return True

    bus.request_state(kickcat.State.SAFE_OP)
    bus.wait_for_state(kickcat.State.SAFE_OP, 2.0)
    cycle()
    bus.request_state(kickcat.State.OPERATIONAL)
    bus.wait_for_state(kickcat.State.OPERATIONAL, 2.0, cycle)
    out["op"] = [str(bus.get_state(s)) for s in slaves]
    bad["wkc"] = bad["lost"] = 0      # the bring-up cycles run before every slave takes outputs
    echo: list[list[int]] = []
    dio = slaves[1]
    for i in range(cycles):
        pattern = (i * 37) & 0xFF
        dio.set_output_bytes(bytes([pattern]))
        time.sleep(0.001)
        if cycle():
            echo.append([i, pattern, bytes(dio.input_data)[0]])
    out.update(bad_wkc=bad["wkc"], lost=bad["lost"], echo=echo)
    bus.request_state(kickcat.State.INIT)
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], int(sys.argv[2]))))
