"""Runs one esd host scenario with a PysoemBackend (inside the test's network namespace).

Usage: python esd_host_driver.py INTERFACE SCENARIO   -> one JSON line on stdout; exit 1 + traceback on failure.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from esd_host_scenarios import SCENARIOS

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend

#: Opening the line (config_init, mailbox SMs, INIT -> PREOP) on a loaded machine may lose a frame
#: (AL 0x0016 from a mailbox SM write that never arrived); a fresh open repairs it.
OPEN_ATTEMPTS = 3


def open_backend(iface: str) -> PysoemBackend:
    for attempt in range(OPEN_ATTEMPTS):
        try:
            return PysoemBackend(iface, timeout=5.0, pd_timeout_us=50_000)
        except GatewaylabError:
            if attempt == OPEN_ATTEMPTS - 1:
                raise
            RealTimeClock().wait(0.5)   # lets the emulator's wire thread catch up
    raise AssertionError("unreachable")


if __name__ == "__main__":
    iface, name = sys.argv[1], sys.argv[2]
    backend = open_backend(iface)
    try:
        result = SCENARIOS[name][0](backend)
    finally:
        backend.close()
    print(json.dumps(result))
