"""The master side of the user-path storm (issue 21): run inside the test's network namespace, prints one
JSON line.

Usage: python storm_kit.py INTERFACE SEED MAX_FRAMES MAX_SECONDS CYCLES

1. SOEM (pysoem) brings the line to OP, as a user's application does, and learns each slave's station
   address and mailbox SyncManagers; the application then goes away without a goodbye.
2. Mutated EtherCAT frames (tests/ethercat/ethercat_storm.py ``mutated_storm``: the master's own datagrams
   with commands, addresses and lengths changed, SyncManagers and FMMUs programmed over the registers,
   CoE requests into the mailbox; no SII write enable) go out on the raw socket, at most MAX_FRAMES in at
   most MAX_SECONDS, answers drained as they come.
3. A new SOEM master re-initialises the line the normal way: ``config_init`` (INIT with acknowledge,
   SM0-3 and FMMU0-2 cleared, mailboxes), then what IgH and KickCAT also clear and set on every
   start-up (every FMMU and SyncManager 4-15, DC SYNC activation off, watchdog divider and times),
   ``config_map``, SAFEOP, OP, and CYCLES process data cycles.
"""

from __future__ import annotations

import json
import select
import socket
import struct
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "ethercat"))

from ethercat_soem_driver import RX_TIMEOUT_US, SLOW_US, _open, _to_op
from ethercat_storm import MasterTemplates, mutated_storm

ETHERTYPE = 0x88A4
SM = struct.Struct("<HHBBBB")
WD_DIVIDER = struct.pack("<H", 2498)  # 100 us ticks (ET1100 0x0400 after power-on)
WD_TIME_1S = struct.pack("<H", 10_000)  # 0x0410 / 0x0420: 10,000 ticks of 100 us


def learn_line(iface: str) -> tuple[list[int], list[tuple[int, int, int, int]], dict[str, Any]]:
    """SOEM up to OP; each slave's station address and (SM0 start, size, SM1 start, size)."""
    master = _open(iface)
    n = master.config_init()
    stations, mailboxes = [], []
    for s in master.slaves:
        sm0 = SM.unpack(s._fprd(0x0800, 8, SLOW_US))
        sm1 = SM.unpack(s._fprd(0x0808, 8, SLOW_US))
        has_mbx = bool(sm0[4] & 1) and (sm0[2] & 0x03) == 0x02
        stations.append(int.from_bytes(s._fprd(0x0010, 2, SLOW_US), "little"))
        mailboxes.append((sm0[0], sm0[1], sm1[0], sm1[1]) if has_mbx else (0, 0, 0, 0))
    info = {"count": n, **_to_op(master)}
    master.close()
    return stations, mailboxes, info


def send_storm(iface: str, frames: list[bytes], max_seconds: float) -> dict[str, int]:
    rx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETHERTYPE))
    rx.bind((iface, ETHERTYPE))
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    tx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
    tx.bind((iface, 0))
    sent = replies = 0
    deadline = time.monotonic() + max_seconds
    for i, frame in enumerate(frames):
        if time.monotonic() >= deadline:
            break
        tx.send(frame.ljust(60, b"\0"))
        sent += 1
        if i % 32 == 31:  # let the rig keep up a little (its socket buffer is 1 MB)
            while select.select([rx], [], [], 0.001)[0]:
                rx.recv(2048)
                replies += 1
    quiet = time.monotonic() + 10.0
    while time.monotonic() < quiet and select.select([rx], [], [], 0.3)[0]:
        rx.recv(2048)
        replies += 1
    tx.close()
    rx.close()
    return {"sent": sent, "replies": replies}


def reinitialise(iface: str, cycles: int) -> dict[str, Any]:
    """A normal master start-up on a line in an unknown state; a start that lost a register frame to a
    stall of the shared VM (SOEM waits 2 ms for those) is begun again, at most three times."""
    master = _open(iface)
    out: dict[str, Any] = {"attempts": []}
    out.update(op=0, count=0, names=[])
    for _ in range(3):
        try:
            out["count"] = master.config_init()
            out["names"] = [s.name for s in master.slaves]
            for s in master.slaves:
                s._fpwr(0x0600, bytes(16 * 16), SLOW_US)  # every FMMU
                s._fpwr(0x0820, bytes(8 * 12), SLOW_US)  # SyncManagers 4-15 (config_init programmed 0-1)
                s._fpwr(0x0981, b"\0", SLOW_US)  # DC SYNC activation off
                s._fpwr(0x0400, WD_DIVIDER, SLOW_US)
                s._fpwr(0x0410, WD_TIME_1S, SLOW_US)
                s._fpwr(0x0420, WD_TIME_1S, SLOW_US)
            out.update(_to_op(master))
            master.read_state()
            out["attempts"].append({"op": out["op"], "states": [(s.state, s.al_status) for s in master.slaves]})
        except Exception as exc:  # a line that never recovers: reported, not a crash of the driver
            out["attempts"].append({"error": f"{type(exc).__name__}: {exc}"})
            continue
        if out["op"] == 8:
            break
    bad = cycles
    if out["op"] == 8:
        bad = 0
        for _ in range(cycles):
            master.send_processdata()
            if master.receive_processdata(RX_TIMEOUT_US) != master.expected_wkc:
                bad += 1
        master.read_state()
    out["bad_wkc"] = bad
    out["cycles"] = cycles
    out["states"] = [s.state for s in master.slaves]
    master.close()
    return out


if __name__ == "__main__":
    iface, seed, max_frames = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    max_seconds, cycles = float(sys.argv[4]), int(sys.argv[5])
    stations, mailboxes, before = learn_line(iface)
    frames = mutated_storm(seed, max_frames, MasterTemplates(stations, mailboxes))
    result: dict[str, Any] = {"before": before, "stations": stations, "mailboxes": mailboxes,
                              "storm": send_storm(iface, frames, max_seconds)}
    result.update(reinitialise(iface, cycles))
    print(json.dumps(result))
