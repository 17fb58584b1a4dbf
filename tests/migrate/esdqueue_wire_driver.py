"""Runs the esd-API application of test_migrate_esdqueue_wire.py with a PysoemBackend (inside the
test's network namespace) against the gateway on the other veth end.

Usage: python esdqueue_wire_driver.py INTERFACE esd|ecanlite -> one JSON line on stdout; exit 1 +
traceback on failure.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.hosts.esd_can_ethercat import BitRate, EsdHost, EsdQueueApi, FilterArea
from gatewaylab.migrate.esdqueue import EsdQueueOnEcanLite

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tests/: kit_paths finds the esd host driver
import kit_paths

kit_paths.add_all()
from esd_host_driver import open_backend  # noqa: E402  (the esd host suite's retrying open)

#: Generous seconds for anything that must happen in real time on a loaded machine.
T = 20.0


def application(host: EsdQueueApi) -> dict[str, Any]:
    """The same esd-API code as the in-process suite's: batches, completion, echoes, status, statistics."""
    host.configure(bitrate=BitRate.table6(2), extended=True, filters=(FilterArea(0x200, 0x2FF),
                                                                        FilterArea(0x1000100, 0x10001FF, True)))
    host.start(timeout=T)
    frames = [CanFrame(0x100 + i, bytes([i]) * (i % 9)) for i in range(20)]
    frames += [CanFrame(0x1000000 + i, b"ext", extended=True) for i in range(4)]
    frames.append(CanFrame(0x140, b"", rtr=True, dlc=2))
    tns = host.send(frames, timeout=T)
    host.wait_sent(tns[-1], timeout=T)
    got: list[Any] = []
    deadline = host.clock.now() + T
    while len(got) < len(frames) and host.clock.now() < deadline:
        got += host.receive(timeout=0.1)
    stats = host.statistics()
    status = host.status()
    completed = [host.completed(t) for t in tns]
    host.stop()
    return {"tns": tns, "completed": completed,
            "echoes": [[r.frame.can_id, r.frame.data.hex(), r.frame.extended, r.frame.rtr] for r in got],
            "status": dataclasses.asdict(status),
            "tx": stats["CAN Frames TX"], "rx": stats["CAN Frames RX"]}


if __name__ == "__main__":
    iface, kind = sys.argv[1], sys.argv[2]
    backend = open_backend(iface)
    try:
        host: EsdQueueApi = (EsdHost(backend, cycle_time=0.005) if kind == "esd"
                             else EsdQueueOnEcanLite(backend, cycle_time=0.005))
        result = application(host)
    finally:
        backend.close()
    print(json.dumps(result))
