"""pysoem master for the esd CAN-EtherCAT latency test of the user's path, run in a subprocess inside
the test's network namespace; prints one JSON line.

Usage: python esd_latency_driver.py INTERFACE BATCHES EVERY_MS

Brings the gateway up as the manual's 4.3 says, with the esd wire tests' SOEM steps
(tests/esd_can_ethercat/esd_soem_driver.py: PREOP, 0xF800:02 = 2 for 500 kbit/s, the mapping read by
SDO, SAFEOP, OP while exchanging process data), then sends ``BATCHES`` Tx batches
through the MDP 5000 counter handshake (5.1.5.3): the first one in the very first cycle after OP, the
next ones ``EVERY_MS`` apart (each once the last one was acknowledged). Batch ``b`` carries
``FRAMES`` frames, id ``BASE_ID + k``, data ``(b, k)`` as two bytes. For each batch it records the
wall time (``time.time()``) of the cycle that wrote it and of the cycle that saw it acknowledged
(input Tx counter equal); the test matches them with a python-can client's receive timestamps.
Struct packing of its own (and of esd_soem_driver.py), independent of the emulator's codec.
"""

from __future__ import annotations

import json
import struct
import sys
import time
from pathlib import Path
from typing import Any

import pysoem

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tests/: kit_paths finds the esd wire driver
import kit_paths

kit_paths.add_all()
from esd_soem_driver import IN_HDR, OUT_HDR, _init, _open, _retry, _to_op  # noqa: E402

CYCLE = 0.001
RX_TIMEOUT_US = 20_000          # 20 ms for process data (a loaded 2-CPU machine)
TX11 = struct.Struct("<HH8s")
BASE_ID = 0x300
FRAMES = 4


def _ticks() -> Any:
    """Yield forever at 1 ms ticks (sleep, then spin the last 0.3 ms), like a real-time task."""
    t_next = time.perf_counter() + CYCLE
    while True:
        slack = t_next - time.perf_counter() - 0.0003
        if slack > 0:
            time.sleep(slack)
        while time.perf_counter() < t_next:
            pass
        t_next += CYCLE
        yield


def main(iface: str, batches: int, every_ms: float) -> dict[str, Any]:
    master = _open(iface)
    if not _init(master):
        return {"op": False, "state": "no slave found"}
    s = master.slaves[0]
    _retry(s.sdo_write, 0xF800, 2, bytes([2]))               # 500 kbit/s (Table 6)
    _retry(s.set_watchdog, "processdata", 1000)
    state = _to_op(master)
    if state != "OP":
        return {"op": False, "state": state}
    op_at = time.time()
    ticks = _ticks()
    outputs = bytearray(len(s.output))
    sent: list[float] = []
    acked: list[float] = []
    late = 0
    tx_counter = 0
    tn = 0
    waiting = False
    next_at = 0.0
    deadline = time.monotonic() + 10 + batches * every_ms / 1000
    while (len(acked) < batches) and time.monotonic() < deadline:
        next(ticks)
        inputs = bytes(s.input)
        in_tx = IN_HDR.unpack_from(inputs, 0)[0] if len(inputs) >= IN_HDR.size else -1
        now = time.time()
        if waiting and in_tx == tx_counter:
            acked.append(now)
            waiting = False
        if not waiting and len(sent) < batches and now >= next_at:
            b = len(sent)
            body = b"".join(TX11.pack(tn + k + 1, (BASE_ID + k) << 5 | 2, bytes([b & 0xFF, k]))
                            for k in range(FRAMES))
            tn += FRAMES
            tx_counter = (tx_counter + 1) & 0xFFFF
            outputs[OUT_HDR.size:OUT_HDR.size + len(body)] = body
            OUT_HDR.pack_into(outputs, 0, tx_counter, 0, FRAMES)
            s.output = bytes(outputs)
            sent.append(time.time())
            next_at = sent[-1] + every_ms / 1000
            waiting = True
        master.send_processdata()
        if master.receive_processdata(RX_TIMEOUT_US) != master.expected_wkc:
            late += 1
    out = {"op": True, "op_at": op_at, "sent": sent, "acked": acked, "late_cycles": late, "frames": FRAMES,
           "base_id": BASE_ID}
    master.state = pysoem.INIT_STATE
    master.write_state()
    master.close()
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]))))
