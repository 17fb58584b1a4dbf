"""pysoem master run in a subprocess (inside the test's network namespace); prints one JSON result.

Usage: python ethercat_soem_driver.py INTERFACE SCENARIO [ARGS...]
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import pysoem

#: Correctness, not timing: a frame only counts as lost after 100 ms (the VM is shared and noisy).
RX_TIMEOUT_US = 100_000
SLOW_US = 3_000_000


def _text(value: Any) -> str:
    return value.decode("latin-1") if isinstance(value, bytes) else str(value)


def _open(iface: str) -> Any:
    master = pysoem.Master()
    master.sdo_read_timeout = SLOW_US  # generous: the VM is shared, the test checks behaviour
    master.sdo_write_timeout = SLOW_US
    master.open(iface)
    return master


def scenario_config(iface: str) -> dict[str, Any]:
    master = _open(iface)
    n = master.config_init()
    out: dict[str, Any] = {"count": n, "slaves": []}
    for s in master.slaves:
        out["slaves"].append({"name": s.name, "man": s.man, "id": s.id, "rev": s.rev,
                              "state": s.state})
    master.close()
    return out


def _to_op(master: Any) -> dict[str, Any]:
    info: dict[str, Any] = {}
    master.config_map()
    info["safeop"] = master.state_check(pysoem.SAFEOP_STATE, 50000)
    master.state = pysoem.OP_STATE
    master.send_processdata()
    master.receive_processdata(RX_TIMEOUT_US)
    master.write_state()
    st = pysoem.NONE_STATE
    for _ in range(400):
        master.send_processdata()
        master.receive_processdata(RX_TIMEOUT_US)
        st = master.state_check(pysoem.OP_STATE, 5000)
        if st == pysoem.OP_STATE:
            break
    info["op"] = st
    info["expected_wkc"] = master.expected_wkc
    return info


def scenario_full(iface: str, cycles: int) -> dict[str, Any]:
    master = _open(iface)
    out: dict[str, Any] = {"count": master.config_init()}
    s0 = master.slaves[0]
    out["name_1008"] = s0.sdo_read(0x1008, 0).decode()
    out["identity_vendor"] = int.from_bytes(s0.sdo_read(0x1018, 1), "little")
    out["identity_ca"] = s0.sdo_read(0x1018, 0, 18, True).hex()
    out["long_string"] = s0.sdo_read(0x8000, 1).decode()
    s0.sdo_write(0x8000, 2, (1234).to_bytes(4, "little"))
    out["scale"] = int.from_bytes(s0.sdo_read(0x8000, 2), "little")
    aborts = {}
    for name, call in (("missing", lambda: s0.sdo_read(0x5FFF, 0)),
                       ("missing_sub", lambda: s0.sdo_read(0x1018, 9)),
                       ("read_only", lambda: s0.sdo_write(0x1018, 1, b"\0\0\0\0"))):
        try:
            call()
            aborts[name] = None
        except pysoem.SdoError as exc:
            aborts[name] = exc.abort_code
    out["aborts"] = aborts
    text = bytes(range(33, 127)) * 3 + b"END"
    s0.sdo_write(0x8000, 1, text)  # 285 bytes: normal initiate + segments
    out["segmented_roundtrip"] = s0.sdo_read(0x8000, 1, 512) == text
    out["eeprom_vendor"] = int.from_bytes(s0.eeprom_read(0x0008, 200_000), "little")
    od = {obj.index: obj for obj in s0.od}
    out["od_names"] = {hex(i): _text(od[i].name) for i in (0x1000, 0x1018, 0x1C12, 0x7010) if i in od}
    out["od_count"] = len(od)
    out["od_1018_entries"] = [_text(e.name) for e in od[0x1018].entries] if 0x1018 in od else []
    emergencies: list[int] = []
    s0.add_emergency_callback(lambda e: emergencies.append(e.error_code))
    s0.sdo_write(0x8001, 0, (0x5432).to_bytes(2, "little"))
    deadline = time.monotonic() + 2.0
    while not emergencies and time.monotonic() < deadline:
        s0.mbx_receive()
    out["emergencies"] = emergencies
    payload = bytes(range(256)) * 3 + b"tail"
    s0.foe_write("config.bin", 0, payload, SLOW_US)
    out["foe_roundtrip"] = s0.foe_read("config.bin", 0, 4096, SLOW_US) == payload
    # Long SM watchdog (1 s) so a stall of this shared VM cannot fall back to SAFEOP mid-run.
    for s in master.slaves:
        s.set_watchdog("processdata", 1000)
    out["watchdog_ms"] = master.slaves[0].get_watchdog("processdata")
    out["dc_slaves"] = master.config_dc()
    for s in master.slaves:
        s.dc_sync(True, 1_000_000)
    out.update(_to_op(master))
    bad = lost = 0
    last_good = -1
    inputs: list[str] = []
    t0 = time.perf_counter()
    for i in range(cycles):
        for k, s in enumerate(master.slaves):
            s.output = bytes([(i + k) & 0xFF]) + (i & 0x7FFF).to_bytes(2, "little") \
                + (-k).to_bytes(2, "little", signed=True)
        master.send_processdata()
        wkc = master.receive_processdata(RX_TIMEOUT_US)
        if wkc < 0:         # EC_NOFRAME: no reply within SOEM's timeout -- a lost frame, not a wrong one
            lost += 1
        elif wkc != master.expected_wkc:
            bad += 1
        else:
            last_good = i
            inputs = [s.input.hex() for s in master.slaves]
    out["elapsed"] = time.perf_counter() - t0
    out["bad_wkc"] = bad
    out["lost"] = lost
    out["inputs"] = inputs
    out["last_i"] = last_good
    # stop sending: the SM watchdog (1 s) takes the slaves to SAFEOP + error 0x001B; poll the AL
    # status (register reads do not trigger the process data watchdog) until it happened
    stopped = time.monotonic()
    while time.monotonic() - stopped < 5.0:
        master.read_state()
        if all(s.state & 0x10 for s in master.slaves):
            break
    out["fallback_after_s"] = time.monotonic() - stopped
    out["after_stop"] = [(s.state, s.al_status) for s in master.slaves]
    master.close()
    return out


def scenario_mixed(iface: str) -> dict[str, Any]:
    """A CoE slave followed by a slave without mailbox (process data sizes from SII categories)."""
    master = _open(iface)
    out: dict[str, Any] = {"count": master.config_init()}
    out["names"] = [s.name for s in master.slaves]
    out["image"] = master.config_map()
    out.update(_to_op(master))
    master.slaves[1].output = b"\x0f"
    wkcs: list[int] = []
    lost = 0
    while len(wkcs) < 3 and lost < 3:       # three replies; a lost frame (EC_NOFRAME) is counted
        master.send_processdata()
        wkc = master.receive_processdata(RX_TIMEOUT_US)
        if wkc < 0:
            lost += 1
        else:
            wkcs.append(wkc)
    out["wkcs"] = wkcs
    out["lost"] = lost
    out["dio_input"] = master.slaves[1].input.hex()
    master.close()
    return out


def scenario_cycles(iface: str, cycles: int) -> dict[str, Any]:
    """Map whatever the slaves offer, go to OP, run cycles writing a counter pattern to slave 1."""
    master = _open(iface)
    out: dict[str, Any] = {"count": master.config_init()}
    out["names"] = [s.name for s in master.slaves]
    out["image"] = master.config_map()
    out.update(_to_op(master))
    s0 = master.slaves[0]
    size = len(s0.output)
    bad = lost = 0
    out["last_i"], out["input"] = -1, ""
    for i in range(cycles):
        s0.output = bytes([i & 0xFF]) * size
        master.send_processdata()
        wkc = master.receive_processdata(RX_TIMEOUT_US)
        if wkc < 0:         # EC_NOFRAME: a lost frame (counted), not a wrong answer
            lost += 1
        elif wkc != master.expected_wkc:
            bad += 1
        else:
            out["last_i"], out["input"] = i, s0.input.hex()
    out["bad_wkc"] = bad
    out["lost"] = lost
    out["sizes"] = [len(s0.output), len(s0.input)]
    master.close()
    return out


if __name__ == "__main__":
    iface, scenario = sys.argv[1], sys.argv[2]
    if scenario == "config":
        result = scenario_config(iface)
    elif scenario == "mixed":
        result = scenario_mixed(iface)
    elif scenario == "cycles":
        result = scenario_cycles(iface, int(sys.argv[3]))
    else:
        result = scenario_full(iface, int(sys.argv[3]) if len(sys.argv) > 3 else 1000)
    print(json.dumps(result))
