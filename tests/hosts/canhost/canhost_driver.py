"""The canopen application of the pysoem test, run inside the test's network namespace.

Usage: python canhost_driver.py INTERFACE_NAME IFNAME  -> one JSON line on stdout; exit 1 + traceback
on failure. INTERFACE_NAME is the python-can interface (``ecanlite`` or ``esd_can_ethercat``); the
arguments are those of the in-process test (test_canhost_canopen.INTERFACES).
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import can
import canopen

sys.path.insert(0, str(Path(__file__).parent))

from test_canhost_canopen import INTERFACES, move_pp

if __name__ == "__main__":
    interface, ifname = sys.argv[1], sys.argv[2]
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    for attempt in range(3):   # a veth link just brought up may lose the first frames: open again
        try:
            # pd_timeout_us: SOEM waits up to 50 ms for the process data (a loaded 2-core machine)
            net.connect(interface=interface, channel=ifname, cycle_us=1000, pd_timeout_us=50_000,
                        **INTERFACES[interface])
            break
        except can.CanInitializationError:
            if attempt == 2:
                raise
    try:
        node = net.add_node(2, canopen.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = 2.0      # a loaded 2-core machine: generous, never asserted
        name = node.sdo.upload(0x1008, 0).decode()
        serial = struct.unpack("<I", node.sdo.upload(0x1018, 4))[0]
        host = net.bus.host   # type: ignore[attr-defined]
        try:
            pos, sw = move_pp(node, host, 20_000)
        except Exception:
            print(f"host: {host.cycles} cycles, {host.wkc_errors} WKC errors, {host.recoveries} recoveries",
                  file=sys.stderr)
            raise
        result = {"name": name, "serial": serial, "position": pos, "statusword": sw, "cycles": host.cycles,
                  "wkc_errors": host.wkc_errors, "recoveries": host.recoveries}
    finally:
        net.disconnect()
    print(json.dumps(result))
