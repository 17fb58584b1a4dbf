"""pysoem master that replays an ENI's InitCmds, as TwinCAT and the QEC master do; prints one JSON result.

Usage: python eni_soem_driver.py INTERFACE ENI CYCLES

SOEM finds the slaves (``config_init`` with ``manual_state_change``: SOEM changes no state itself), then each
transition of the ENI is replayed in order (ETG.2100 ``InitCmd/Transition``): for INIT->PREOP the register
InitCmds, for PREOP->SAFEOP the CoE InitCmds (SDO downloads), ``config_map`` (SOEM reads the PDO
assignment the downloads made and maps the process data), then the register InitCmds (SyncManagers, FMMUs,
the AL control request and the AL status check), for SAFEOP->OP the same after one process data cycle.
Register InitCmds go out as the datagram pysoem offers for one slave (FPWR for APWR/FPWR, FPRD for
APRD/FPRD: the station address the ENI names, or the slave at the auto-increment position) with SOEM's default
timeout and no retry; each must return the ENI's ``Cnt`` (1); a ``Validate`` reads until the masked data
match or its timeout passes (a poll without reply counts as one more poll, as the loop polls anyway).
Then CYCLES process data cycles 1 ms apart against the ENI's cyclic working counter.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import pysoem

from gatewaylab.ethercat.eni import Eni, RegisterInitCmd, parse_eni_xml

TIMEOUT_US = 2000          # SOEM's EC_TIMEOUTRET
WRITES = {2, 5}            # APWR, FPWR
READS = {1, 4}             # APRD, FPRD
STATE_REGS = {0x0120, 0x0130}


class Replay:
    """The master and the ENI; every exchange counted, every failure recorded."""

    def __init__(self, master: Any, eni: Eni) -> None:
        self.master = master
        self.eni = eni
        self.by_station = {0x1001 + i: i for i in range(len(master.slaves))}
        self.sent = 0
        self.failures: list[str] = []
        self.per_slave: dict[int, int] = {}
        self.lost_polls = 0

    def _slave(self, cmd: RegisterInitCmd, position: int) -> Any:
        if cmd.cmd in (1, 2):                      # auto-increment: 0, -1, -2 ... (the ENI's Adp)
            return self.master.slaves[(-cmd.adp) & 0xFFFF]
        return self.master.slaves[self.by_station[cmd.adp]]

    def register(self, position: int, cmd: RegisterInitCmd) -> None:
        what = f"slave {position} {cmd.comment!r} ({cmd.cmd} 0x{cmd.ado:04X})"
        if cmd.cmd not in WRITES | READS or cmd.cnt not in (None, 1):
            self.failures.append(f"{what}: not replayable with pysoem")
            return
        slave = self._slave(cmd, position)
        self.sent += 1
        self.per_slave[position] = self.per_slave.get(position, 0) + 1
        try:
            if cmd.cmd in WRITES:
                slave._fpwr(cmd.ado, cmd.data, TIMEOUT_US)
                return
            if cmd.validate is None:
                slave._fprd(cmd.ado, len(cmd.data), TIMEOUT_US)
                return
            deadline = time.monotonic() + cmd.timeout_ms / 1000
            while True:
                try:
                    data = slave._fprd(cmd.ado, len(cmd.data), TIMEOUT_US)
                except pysoem.WkcError:     # a poll of the Validate loop without reply: the next poll follows
                    self.lost_polls += 1
                    if time.monotonic() > deadline:
                        raise
                    continue
                mask = cmd.validate_mask or bytes([0xFF] * len(cmd.validate))
                if all((a & m) == (b & m) for a, b, m in zip(data, cmd.validate, mask)):
                    return
                if time.monotonic() > deadline:
                    code = int.from_bytes(slave._fprd(0x0134, 2, TIMEOUT_US), "little")
                    self.failures.append(f"{what}: read {data.hex()}, expected {cmd.validate.hex()} mask {mask.hex()} "
                                         f"(AL status code 0x{code:04X})")
                    return
                time.sleep(0.001)
        except pysoem.WkcError:
            self.failures.append(f"{what}: wrong working counter (expected {cmd.cnt or 1})")

    def registers(self, transition: str, state: bool) -> None:
        for s in self.eni.slaves:
            for cmd in s.init_cmds:
                if transition in cmd.transitions and (cmd.ado in STATE_REGS) == state:
                    self.register(s.position, cmd)

    def coe(self, transition: str) -> int:
        done = 0
        for s in self.eni.slaves:
            for c in s.coe_cmds:
                if transition not in c.transitions or c.ccs != 1:
                    continue
                try:
                    self.master.slaves[s.position].sdo_write(c.index, c.subindex, c.data, c.complete_access)
                    done += 1
                except pysoem.SdoError as exc:
                    self.failures.append(f"slave {s.position} CoE 0x{c.index:04X}:{c.subindex:02X}: abort "
                                         f"0x{exc.abort_code:08X} {exc.desc}")
        return done


def main() -> None:
    ifname, eni_path, cycles = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
    eni = parse_eni_xml(eni_path.read_bytes(), eni_path.name)
    master = pysoem.Master()
    master.open(ifname)
    result: dict[str, Any] = {}
    try:
        master.manual_state_change = True
        result["count"] = master.config_init()
        result["identities"] = [[s.man, s.id, s.rev] for s in master.slaves]
        replay = Replay(master, eni)
        replay.registers("IP", state=False)
        replay.registers("IP", state=True)
        master.read_state()
        result["preop"] = sum(s.state == pysoem.PREOP_STATE for s in master.slaves)
        result["coe"] = replay.coe("PS")
        master.config_map()
        result["soem_sms"] = [master.slaves[i]._fprd(0x0800, 32, TIMEOUT_US).hex() for i in range(len(master.slaves))]
        replay.registers("PS", state=False)
        replay.registers("PS", state=True)
        master.read_state()
        result["safeop"] = sum(s.state == pysoem.SAFEOP_STATE for s in master.slaves)
        master.send_processdata()
        master.receive_processdata(TIMEOUT_US)
        replay.coe("SO")
        replay.registers("SO", state=False)
        replay.registers("SO", state=True)
        master.read_state()
        result["op"] = sum(s.state == pysoem.OP_STATE for s in master.slaves)
        result["expected_wkc"] = master.expected_wkc
        wkcs: dict[int, int] = {}
        lost = 0
        gaps: list[float] = []
        last = time.monotonic()
        for _ in range(cycles):
            now = time.monotonic()
            gaps.append(now - last)
            last = now
            master.send_processdata()
            wkc = master.receive_processdata(TIMEOUT_US)
            if wkc <= 0:
                lost += 1
            else:
                wkcs[wkc] = wkcs.get(wkc, 0) + 1
            time.sleep(0.001)
        result.update(lost_polls=replay.lost_polls, wkcs={str(k): v for k, v in wkcs.items()}, lost=lost,
                      sent=replay.sent,
                      per_slave={str(k): v for k, v in replay.per_slave.items()}, failures=replay.failures,
                      sizes=[[len(s.output), len(s.input)] for s in master.slaves])
        master.read_state()
        result["final"] = [[s.state, s.al_status] for s in master.slaves]
        result["max_gap_ms"] = max(gaps) * 1000
        master.state = pysoem.INIT_STATE
        master.write_state()
    finally:
        master.close()
    print(json.dumps(result))


if __name__ == "__main__":
    main()
