"""pysoem master for the slave-fault wire tests, run inside the test's network namespace.

Usage: python ethercat_slave_faults_driver.py INTERFACE. It reads one JSON command per line on stdin and
answers each with one JSON line on stdout, so the test can inject a fault (``gatewaylab fault``) between
two steps of one master session (the master is never restarted):

``init``: open + config_init (each slave's name, man, id); ``config_init``: again (identity re-read);
``map``: config_map (SOEM requests SAFEOP) and the states read back; ``to_op``: config_map, SAFEOP, OP
with process data; ``cycles`` N: N process data cycles 1 ms apart (working counters); ``state`` SLAVE
STATE [ack]: request a state for one slave and read back state and AL status code (SOEM
``ecx_readstate``); ``read_state``; ``sdo_read`` SLAVE INDEX SUB [timeout_us, size]; ``sdo_write`` SLAVE INDEX SUB
DATA (hex); ``eeprom_read`` SLAVE WORD (SOEM's 20 ms EEPROM timeout); ``foe_write`` SLAVE NAME SIZE; ``emcy``
SLAVE: an SDO read with an emergency callback registered.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import pysoem

RX_TIMEOUT_US = 100_000
SDO_TIMEOUT_US = 3_000_000


def _cycle(master: Any) -> int:
    master.send_processdata()
    return int(master.receive_processdata(RX_TIMEOUT_US))


def _states(master: Any) -> list[dict[str, int]]:
    master.read_state()
    return [{"state": s.state, "al_status": s.al_status} for s in master.slaves]


def _error(exc: BaseException) -> dict[str, Any]:
    out: dict[str, Any] = {"error": type(exc).__name__, "text": str(exc)}
    for name in ("abort_code", "error_code", "wkc"):
        if hasattr(exc, name):
            out[name] = getattr(exc, name)
    return out


class Driver:
    def __init__(self, iface: str) -> None:
        self.iface = iface
        self.master = pysoem.Master()
        self.master.sdo_read_timeout = SDO_TIMEOUT_US
        self.master.sdo_write_timeout = SDO_TIMEOUT_US

    def init(self, cmd: dict[str, Any]) -> dict[str, Any]:
        self.master.open(self.iface)
        return self.config_init(cmd)

    def config_init(self, cmd: dict[str, Any]) -> dict[str, Any]:
        n = self.master.config_init()
        return {"count": n, "slaves": [{"name": s.name, "man": s.man, "id": s.id} for s in self.master.slaves]}

    def map(self, cmd: dict[str, Any]) -> dict[str, Any]:
        self.master.config_map()
        self.master.state_check(pysoem.SAFEOP_STATE, 50000)
        return {"states": _states(self.master)}

    def to_op(self, cmd: dict[str, Any]) -> dict[str, Any]:
        master = self.master
        master.config_map()
        for s in master.slaves:          # the master's choice: no SM watchdog (the test steps are slow)
            s._fpwr(pysoem.ECT_REG_WD_TIME_PROCESSDATA, b"\0\0")
        safeop = master.state_check(pysoem.SAFEOP_STATE, 50000)
        master.state = pysoem.OP_STATE
        _cycle(master)
        master.write_state()
        st = pysoem.NONE_STATE
        for _ in range(400):
            _cycle(master)
            st = master.state_check(pysoem.OP_STATE, 5000)
            if st == pysoem.OP_STATE:
                break
        return {"safeop": safeop, "op": st, "expected_wkc": master.expected_wkc}

    def cycles(self, cmd: dict[str, Any]) -> dict[str, Any]:
        wkcs = []
        for _ in range(int(cmd.get("n", 20))):
            wkcs.append(_cycle(self.master))
            time.sleep(0.001)
        return {"wkc": wkcs, "expected_wkc": self.master.expected_wkc}

    def state(self, cmd: dict[str, Any]) -> dict[str, Any]:
        slave = self.master.slaves[int(cmd["slave"])]
        want = int(cmd["state"])
        slave.state = want | (pysoem.STATE_ACK if cmd.get("ack") else 0)
        slave.write_state()
        deadline = time.monotonic() + 2.0
        while True:
            if want == pysoem.OP_STATE:
                _cycle(self.master)
            states = _states(self.master)
            mine = states[int(cmd["slave"])]
            if mine["state"] == want or mine["state"] & pysoem.STATE_ERROR or time.monotonic() > deadline:
                return {"states": states}
            time.sleep(0.002)

    def read_state(self, cmd: dict[str, Any]) -> dict[str, Any]:
        return {"states": _states(self.master)}

    def sdo_read(self, cmd: dict[str, Any]) -> dict[str, Any]:
        self.master.sdo_read_timeout = int(cmd.get("timeout_us", SDO_TIMEOUT_US))
        try:
            data = self.master.slaves[int(cmd["slave"])].sdo_read(int(cmd["index"]), int(cmd["sub"]),
                                                                   int(cmd.get("size", 0)))
            return {"data": data.hex()}
        except Exception as exc:            # the test asserts what the master raised
            return _error(exc)
        finally:
            self.master.sdo_read_timeout = SDO_TIMEOUT_US

    def sdo_write(self, cmd: dict[str, Any]) -> dict[str, Any]:
        try:
            self.master.slaves[int(cmd["slave"])].sdo_write(int(cmd["index"]), int(cmd["sub"]),
                                                             bytes.fromhex(cmd["data"]))
            return {"done": True}
        except Exception as exc:
            return _error(exc)

    def eeprom_read(self, cmd: dict[str, Any]) -> dict[str, Any]:
        return {"data": self.master.slaves[int(cmd["slave"])].eeprom_read(int(cmd["word"])).hex()}

    def foe_write(self, cmd: dict[str, Any]) -> dict[str, Any]:
        data = bytes(i & 0xFF for i in range(int(cmd["size"])))
        try:
            return {"result": self.master.slaves[int(cmd["slave"])].foe_write(str(cmd["name"]), 0, data)}
        except Exception as exc:
            return _error(exc)

    def emcy(self, cmd: dict[str, Any]) -> dict[str, Any]:
        slave = self.master.slaves[int(cmd["slave"])]
        seen: list[dict[str, int]] = []
        slave.add_emergency_callback(lambda e: seen.append(
            {"error_code": e.error_code, "error_reg": e.error_reg, "b1": e.b1, "w1": e.w1, "w2": e.w2}))
        try:
            out: dict[str, Any] = {"data": slave.sdo_read(0x1018, 1).hex()}
        except Exception as exc:
            out = _error(exc)
        out["emergencies"] = seen
        return out


def main() -> int:
    driver = Driver(sys.argv[1])
    for line in sys.stdin:
        cmd = json.loads(line)
        if cmd["do"] == "quit":
            break
        try:
            answer = getattr(driver, cmd["do"])(cmd)
        except Exception as exc:
            answer = {"failed": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(answer), flush=True)
    driver.master.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
