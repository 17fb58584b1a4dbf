"""Runs one esd host scenario with a PysoemBackend (inside the test's network namespace).

Usage: python esd_host_driver.py INTERFACE SCENARIO   -> one JSON line on stdout; exit 1 + traceback on failure.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from esd_host_scenarios import SCENARIOS

from gatewaylab.ethercat.backend import PysoemBackend

if __name__ == "__main__":
    iface, name = sys.argv[1], sys.argv[2]
    backend = PysoemBackend(iface, timeout=5.0, pd_timeout_us=50_000)
    try:
        result = SCENARIOS[name][0](backend)
    finally:
        backend.close()
    print(json.dumps(result))
