"""Runs one MasterBackend contract check with a PysoemBackend (inside the test's network namespace).

Usage: python ec_backend_driver.py INTERFACE CHECK   -> one JSON line on stdout; exit 1 + traceback on failure.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from ec_contract import CHECKS

from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend

if __name__ == "__main__":
    iface, check = sys.argv[1], sys.argv[2]
    backend = PysoemBackend(iface)
    try:
        result = CHECKS[check](backend)
    finally:
        backend.close()
    print(json.dumps(result))
