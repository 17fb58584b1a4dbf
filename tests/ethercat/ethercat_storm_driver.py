"""Storm sender + SOEM master, run in a subprocess inside the test's network namespace; prints one JSON line.

Usage: python ethercat_storm_driver.py INTERFACE SEED COUNT CYCLES

Sends COUNT random frames (ethercat_storm.py, SII writes disabled) on INTERFACE, waits until the
emulator has answered what it answers (0.5 s of silence, at most 20 s), then lets pysoem
re-initialise the segment, go to OP and run CYCLES process data cycles.
"""

from __future__ import annotations

import json
import math
import select
import socket
import sys
import time
from collections.abc import Callable, Iterable
from typing import Any

from ethercat_soem_driver import RX_TIMEOUT_US, SLOW_US, _open, _to_op
from ethercat_storm import storm

ETHERTYPE = 0x88A4
WD_DIVIDER_DEFAULT = (2498).to_bytes(2, "little")  # 100 us ticks (ET1100 0x0400 after power-on)
WD_TIME_1S = (10_000).to_bytes(2, "little")  # SM watchdog 0x0420: 10,000 ticks of 100 us


def send_storm(iface: str, frames: Iterable[bytes], max_seconds: float = math.inf) -> dict[str, int]:
    """Send ``frames`` (for at most ``max_seconds``), draining answers as they come, then wait until the
    emulator has answered what it answers (0.5 s of silence, at most 20 s)."""
    rx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETHERTYPE))
    rx.bind((iface, ETHERTYPE))
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    tx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
    tx.bind((iface, 0))
    sent = replies = 0
    stop = time.monotonic() + max_seconds
    for i, frame in enumerate(frames):
        if time.monotonic() >= stop:
            break
        tx.send(frame.ljust(60, b"\0"))
        sent += 1
        if i % 64 == 63:  # let the emulator keep up a little (its socket buffer is 1 MB)
            while select.select([rx], [], [], 0.002)[0]:
                rx.recv(2048)
                replies += 1
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline and select.select([rx], [], [], 0.5)[0]:
        rx.recv(2048)
        replies += 1
    tx.close()
    rx.close()
    return {"sent": sent, "replies": replies}


def reset_watchdogs(slave: Any) -> None:
    """The storm may have left any SM watchdog divider and time behind: 100 us ticks, 1 s."""
    slave._fpwr(0x0400, WD_DIVIDER_DEFAULT, SLOW_US)
    slave._fpwr(0x0420, WD_TIME_1S, SLOW_US)


def soem_after_storm(iface: str, cycles: int, reset: Callable[[Any], None] = reset_watchdogs) -> dict[str, Any]:
    """config_init, ``reset`` of each slave, then OP; a bring-up that lost a register frame to a stall of
    this shared VM (SOEM waits 2 ms for those) is started again from config_init, at most three times.
    A bring-up that raises is recorded in ``attempts`` (a line that never recovers is a result, not a
    crash of the driver)."""
    master = _open(iface)
    out: dict[str, Any] = {"attempts": [], "op": 0, "count": 0, "names": []}
    for _ in range(3):
        try:
            out["count"] = master.config_init()
            out["names"] = [s.name for s in master.slaves]
            for s in master.slaves:
                reset(s)
            out.update(_to_op(master))
            master.read_state()
        except Exception as exc:
            out["attempts"].append({"error": f"{type(exc).__name__}: {exc}"})
            continue
        out["attempts"].append({"op": out["op"], "states": [(s.state, s.al_status) for s in master.slaves]})
        if out["op"] == 8:
            break
    bad = 0 if out["op"] == 8 else cycles
    lost = 0
    for i in range(cycles if out["op"] == 8 else 0):
        for k, s in enumerate(master.slaves):
            s.output = bytes([(i + k) & 0xFF]) + bytes(len(s.output) - 1)
        master.send_processdata()
        wkc = master.receive_processdata(RX_TIMEOUT_US)
        if wkc < 0:         # EC_NOFRAME: a lost frame (counted), not a wrong answer
            lost += 1
        elif wkc != master.expected_wkc:
            bad += 1
    master.read_state()
    out["bad_wkc"] = bad
    out["lost"] = lost
    out["cycles"] = cycles
    out["states"] = [s.state for s in master.slaves]
    out["inputs"] = [s.input.hex() for s in master.slaves]
    master.close()
    return out


if __name__ == "__main__":
    iface, seed, count, cycles = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    result: dict[str, Any] = {"storm": send_storm(iface, storm(seed, count, keep_eeprom=True))}
    result.update(soem_after_storm(iface, cycles))
    print(json.dumps(result))
