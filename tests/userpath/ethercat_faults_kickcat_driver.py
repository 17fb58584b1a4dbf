"""KickCAT master for the EtherCAT fault test on the user's path (run in the test's network namespace):
scan, mapping, OP, then process data every millisecond while it reads commands on stdin, one per line, and
answers each with one JSON line:

* ``mark NAME``: a new phase starts (cycles, lost cycles -- a KickCAT timeout --, INVALID_WKC errors and any
  other error counted per phase) -> ``{"ev": "marked"}``
* ``state``: ``Bus.get_state`` of every slave -> ``{"ev": "state", "states": [...]}``
* ``recover``: what a KickCAT user does after a slave left OP: ``request_state(OPERATIONAL)`` (KickCAT
  writes AL control with the acknowledge bit) and ``wait_for_state`` cycling -> ``{"ev": "recovered", ...}``
* ``asdo SLAVE INDEX SUB``: an SDO upload through KickCAT's mailbox (``slave.mailbox.read_sdo``, its 1 s),
  driven by ``process_mailboxes`` between process data cycles until its status is no longer RUNNING (the
  blocking ``Bus.read_sdo`` stops the cycle meanwhile: the slaves' 100 ms SM watchdogs would expire while an
  SDO waits its timeout) -> ``{"ev": "sdo", "status": ..., "data": HEX}``
* ``end``: ``{"ev": "done", "phases": {...}}``, the slaves to INIT.

KickCAT 2.5's Python ``process_data`` is an LRD then an LWR (the LRW path is not bound); a datagram whose
working counter is not the expected one raises ``RuntimeError`` naming INVALID_WKC, a frame not back within
the link timeout (KickCAT's default 2 ms) raises another one. Defaults everywhere, no retries in the cycles.

Usage: python ethercat_faults_kickcat_driver.py INTERFACE
"""

from __future__ import annotations

import json
import select
import sys
import time
from pathlib import Path
from typing import Any

import kickcat

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tests/: the kits by basename
import kit_paths

kit_paths.add_all()
from kickcat_kit import run_as_kickcat_readme_says, run_step  # noqa: E402

#: KickCAT's defaults: Link.h ``timeout_{2ms}``, Bus.h 1 s per SDO
LINK_TIMEOUT_S = 0.002
SDO_TIMEOUT_S = 1.0
PERIOD_S = 0.001
RUNNING = kickcat.mailbox.request.MessageStatus.RUNNING


class Master:
    def __init__(self, iface: str) -> None:
        run_as_kickcat_readme_says()
        self.iface = iface
        # a scan whose frame came back after the link timeout (a stall of this VM) is started again, every
        # failure printed with the result (kickcat_kit.run_step)
        self.bus, self.retries = run_step("init", self._scan)
        self.slaves = self.bus.slaves()
        self.phases: dict[str, dict[str, Any]] = {}
        self.phase = self.start("bring-up")

    def _scan(self) -> Any:
        self.link = kickcat.create_link(self.iface, "")
        self.link.set_timeout(LINK_TIMEOUT_S)
        bus = kickcat.Bus(self.link)
        bus.init(0.5)
        bus.create_mapping(4096)
        return bus

    def start(self, name: str) -> dict[str, Any]:
        self.phases[name] = {"cycles": 0, "lost": 0, "bad_wkc": 0, "other": [], "bad_at": [], "lost_at": []}
        return self.phases[name]

    def cycle(self) -> bool:
        self.phase["cycles"] += 1
        try:
            self.bus.process_data()
        except RuntimeError as exc:
            text = str(exc)
            if "INVALID_WKC" in text:
                self.phase["bad_wkc"] += 1
                self.phase["bad_at"].append(self.phase["cycles"])
            elif "imeout" in text or "lost" in text.lower():
                self.phase["lost"] += 1
                self.phase["lost_at"].append(self.phase["cycles"])
            else:
                self.phase["other"].append(text)
            return False
        return True

    def to_op(self) -> None:
        self.bus.request_state(kickcat.State.SAFE_OP)
        self.bus.wait_for_state(kickcat.State.SAFE_OP, 2.0)
        self.cycle()
        self.bus.request_state(kickcat.State.OPERATIONAL)
        self.bus.wait_for_state(kickcat.State.OPERATIONAL, 2.0, self.cycle)

    def states(self) -> list[str]:
        """``Bus.get_state`` of each slave; a slave whose AL status has the error flag makes KickCAT raise
        ``ErrorAL`` ("State transition error"): its text then."""
        out = []
        for slave in self.slaves:
            try:
                out.append(str(self.bus.get_state(slave)))
            except kickcat.ErrorAL as exc:
                out.append(f"ErrorAL: {exc} {exc.args!r}")
        return out

    def command(self, line: str) -> dict[str, Any]:
        word, *args = line.split()
        if word == "mark":
            self.phase = self.start(args[0])
            return {"ev": "marked"}
        if word == "state":
            return {"ev": "state", "states": self.states()}
        if word == "recover":
            error = ""
            try:
                self.bus.request_state(kickcat.State.OPERATIONAL)
                self.bus.wait_for_state(kickcat.State.OPERATIONAL, 2.0, self.cycle)
            except RuntimeError as exc:
                error = str(exc)
            return {"ev": "recovered", "states": self.states(), "error": error}
        if word == "asdo":
            slave, index, sub = self.slaves[int(args[0])], int(args[1], 0), int(args[2], 0)
            msg = slave.mailbox.read_sdo(index, sub, False, SDO_TIMEOUT_S)
            polls = 0
            while msg.status() == RUNNING:
                polls += 1
                self.cycle()
                try:
                    self.bus.process_mailboxes()
                except RuntimeError as exc:     # a mailbox check frame not back in time: a lost frame
                    if "LOST" in str(exc) or "imeout" in str(exc):
                        self.phase["lost"] += 1
                    else:
                        self.phase["other"].append(f"mailbox: {exc}")
                time.sleep(PERIOD_S)
            return {"ev": "sdo", "status": msg.status(), "data": bytes(msg.data[:msg.size]).hex(), "polls": polls}
        if word == "end":
            return {"ev": "done", "phases": self.phases, "retries": self.retries}
        return {"ev": "unknown", "line": line}


def main(iface: str) -> None:
    master = Master(iface)
    master.to_op()
    print(json.dumps({"ev": "op", "count": len(master.slaves), "states": master.states(),
                      "sizes": [[s.output_size, s.input_size] for s in master.slaves]}), flush=True)
    master.phase = master.start("base")
    while True:
        master.cycle()
        ready, _, _ = select.select([sys.stdin], [], [], PERIOD_S)
        if not ready:
            continue
        line = sys.stdin.readline()
        answer = master.command(line.strip() or "end")
        print(json.dumps(answer), flush=True)
        if answer["ev"] == "done":
            break
    master.bus.request_state(kickcat.State.INIT)


if __name__ == "__main__":
    main(sys.argv[1])
