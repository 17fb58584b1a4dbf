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
import struct
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import kit_paths

kit_paths.add_all()

from ethercat_soem_driver import SLOW_US, _open, _to_op  # noqa: E402
from ethercat_storm import MasterTemplates, mutated_storm  # noqa: E402
from ethercat_storm_driver import WD_TIME_1S, reset_watchdogs, send_storm, soem_after_storm  # noqa: E402

SM = struct.Struct("<HHBBBB")


def learn_line(iface: str) -> tuple[list[int], list[tuple[int, int, int, int]], dict[str, Any]]:
    """SOEM up to OP; each slave's station address and (SM0 start, size, SM1 start, size). A scan
    that found no slave (a reply later than SOEM's 2 ms on a loaded machine) is repeated, as a user
    would start the application again."""
    master = _open(iface)
    n = master.config_init()
    for _ in range(10):
        if n > 0:
            break
        time.sleep(0.2)
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


def full_reset(slave: Any) -> None:
    """What IgH and KickCAT clear and set on every start-up besides SOEM's config_init."""
    slave._fpwr(0x0600, bytes(16 * 16), SLOW_US)  # every FMMU
    slave._fpwr(0x0820, bytes(8 * 12), SLOW_US)  # SyncManagers 4-15 (config_init programmed 0-1)
    slave._fpwr(0x0981, b"\0", SLOW_US)  # DC SYNC activation off
    slave._fpwr(0x0410, WD_TIME_1S, SLOW_US)  # PDI watchdog 1 s
    reset_watchdogs(slave)  # divider 100 us, SM watchdog 1 s


if __name__ == "__main__":
    iface, seed, max_frames = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    max_seconds, cycles = float(sys.argv[4]), int(sys.argv[5])
    stations, mailboxes, before = learn_line(iface)
    frames = mutated_storm(seed, max_frames, MasterTemplates(stations, mailboxes))
    result: dict[str, Any] = {"before": before, "stations": stations, "mailboxes": mailboxes,
                              "storm": send_storm(iface, frames, max_seconds)}
    result.update(soem_after_storm(iface, cycles, reset=full_reset))
    print(json.dumps(result))
