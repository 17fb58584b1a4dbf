"""A pysoem (SOEM) master with SOEM's default timeouts, cycling one ``ethercat_io`` at 1 kHz, that tells which
request each reply answers (run inside the test's network namespace, beside ``gatewaylab run``).

Every cycle writes its own number into the io's outputs (digital u8 + two int16: 32 bits); the io echoes its
outputs into its inputs within the same LRW (docs/ethercat-io.md), so a reply carries the number of the
request it answers. A reply whose echo is not this cycle's number is a stale one: the answer to an older
request that SOEM matched to this one because it reused the frame index (SOEM keeps 16). Its age is
measured on this side (reply in -> the echoed request's send).

Prints ``{"ev": "op"}`` once cycling in OP, then runs until a line arrives on stdin, then ``SETTLE`` more
seconds, and prints ``{"ev": "done", ...}``: cycles, good replies, lost (no or a short working counter),
stale replies and their ages, the oldest age of any good reply.

Usage: python ethercat_stall_master.py INTERFACE
"""

from __future__ import annotations

import json
import select
import struct
import sys
import time
from typing import Any

import pysoem

PERIOD = 0.001
#: cycles after the test's "go on" line (the stall is over by then)
SETTLE = 1.0
OUT = struct.Struct("<BHH")
IN = struct.Struct("<BHH")


def emit(event: str, **fields: Any) -> None:
    print(json.dumps({"ev": event, **fields}), flush=True)


def encode(n: int) -> bytes:
    return OUT.pack(n & 0xFF, (n >> 8) & 0xFFFF, (n >> 24) & 0xFF)


def decode(data: bytes) -> int:
    lo, mid, hi = IN.unpack_from(data)
    return int(lo | mid << 8 | hi << 24)


def to_op(m: Any) -> None:
    """SOEM's simple_test bring-up with its default timeouts: scan, map, SAFEOP, OP with process data."""
    if m.config_init() != 1:
        raise RuntimeError("SOEM found no slave or more than one")
    m.slaves[0].set_watchdog("processdata", 1000)      # the 200 ms stall must not end OP
    m.config_map()
    if m.state_check(pysoem.SAFEOP_STATE, 50_000) != pysoem.SAFEOP_STATE:
        raise RuntimeError("SAFEOP not reached")
    m.slaves[0].output = encode(0)
    m.state = pysoem.OP_STATE
    m.send_processdata()
    m.receive_processdata()
    m.write_state()
    for _ in range(200):
        m.send_processdata()
        m.receive_processdata()
        if m.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            return
    raise RuntimeError("OP not reached")


def main(iface: str) -> dict[str, Any]:
    m = pysoem.Master()
    m.open(iface)
    to_op(m)
    slave = m.slaves[0]
    sent: dict[int, float] = {}
    out: dict[str, Any] = {"cycles": 0, "good": 0, "lost": 0, "stale": 0, "stale_ages_ms": [], "oldest_ms": 0.0}
    emit("op")
    t_next = time.perf_counter()
    stop_at: float | None = None
    n = 1
    while stop_at is None or time.perf_counter() < stop_at:
        slave.output = encode(n)
        sent[n] = time.perf_counter()
        m.send_processdata()
        wkc = m.receive_processdata()          # SOEM's default: EC_TIMEOUTRET, 2000 us
        t = time.perf_counter()
        out["cycles"] += 1
        if wkc == m.expected_wkc:
            echo = decode(bytes(slave.input))
            age = 1e3 * (t - sent.get(echo, t))
            out["good"] += 1
            out["oldest_ms"] = max(out["oldest_ms"], age)
            if echo != n:
                out["stale"] += 1
                out["stale_ages_ms"].append(round(age, 2))
        else:
            out["lost"] += 1
        n += 1
        if stop_at is None and select.select([sys.stdin], [], [], 0)[0]:
            sys.stdin.readline()
            stop_at = time.perf_counter() + SETTLE
        t_next += PERIOD
        slack = t_next - time.perf_counter()
        if slack > 0:
            time.sleep(slack)
        else:
            t_next = time.perf_counter()
    m.state = pysoem.INIT_STATE
    m.write_state()
    m.close()
    out["stale_ages_ms"] = out["stale_ages_ms"][:50]
    return out


if __name__ == "__main__":
    emit("done", **main(sys.argv[1]))
