"""KickCAT master for the ethercat_drive tests, run in a subprocess inside the test's network
namespace; prints one JSON result (bring-up, CiA 402 enable, CSP ramp, following error fault,
fault reset).

Usage: python ecdrive_kickcat_driver.py INTERFACE
"""

from __future__ import annotations

import json
import struct
import sys
import time
from pathlib import Path
from typing import Any

import kickcat

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))   # tests/: the kits by basename
import kit_paths

kit_paths.add_all()
from kickcat_kit import MAILBOX_ATTEMPTS, run_as_kickcat_readme_says, run_step  # noqa: E402

RX = struct.Struct("<HiihB")
TX = struct.Struct("<HiihbH")
CSP = 8


def scan(iface: str) -> Any:
    """KickCAT's default 2 ms per frame (Link.h): a fresh link and bus, init."""
    link = kickcat.create_link(iface, "")
    link.set_timeout(0.002)
    bus = kickcat.Bus(link)
    bus.init(0.5)
    return bus


def main(iface: str) -> dict[str, Any]:
    run_as_kickcat_readme_says()
    # a step that lost a frame runs again, every failure printed with the result (kickcat_kit.run_step)
    bus, retries = run_step("init", lambda: scan(iface))
    slaves = bus.slaves()
    out: dict[str, Any] = {"count": len(slaves), "retries": retries}

    def sdo(slave: Any, index: int, sub: int, size: int) -> int:
        data, failed = run_step(f"read {index:04X}:{sub}", lambda: bytes(
            bus.read_sdo(slave, index, sub, kickcat.Access.PARTIAL, size, 1.0)), attempts=MAILBOX_ATTEMPTS)
        retries.extend(failed)
        return int.from_bytes(data, "little")

    out["device_type"] = [sdo(s, 0x1000, 0, 4) for s in slaves]
    out["assign"] = [[sdo(s, a, 1, 2) for a in (0x1C12, 0x1C13)] for s in slaves]
    bus.create_mapping(4096)
    out["sizes"] = [[s.output_size, s.input_size] for s in slaves]
    bus.request_state(kickcat.State.SAFE_OP)
    bus.wait_for_state(kickcat.State.SAFE_OP, 1.0)
    outputs = [RX.pack(0, 0, 0, 0, CSP) for _ in slaves]

    lost = [0]

    def cycle() -> None:
        for s, data in zip(slaves, outputs, strict=True):
            s.set_output_bytes(data)
        try:
            bus.process_data()
        except RuntimeError:        # a frame later than the link timeout: counted, not fatal
            lost[0] += 1

    cycle()
    bus.request_state(kickcat.State.OPERATIONAL)
    bus.wait_for_state(kickcat.State.OPERATIONAL, 1.0, cycle)
    out["op"] = [str(bus.get_state(s)) for s in slaves]

    def inp(k: int) -> tuple[int, ...]:
        return tuple(TX.unpack(bytes(slaves[k].input_data)[:TX.size]))

    out["enable"] = []
    for cw in (0x06, 0x07, 0x0F):
        outputs[:] = [RX.pack(cw, 0, 0, 0, CSP) for _ in slaves]
        for _ in range(5):
            cycle()
        out["enable"].append([inp(k)[0] for k in range(len(slaves))])
    worst = 0
    deadline = time.perf_counter()
    for i in range(2000):
        if i:
            worst = max(worst, *(abs(10 * (i - 1) - inp(k)[1]) for k in range(len(slaves))))
        outputs[:] = [RX.pack(0x0F, 10 * i, 0, 0, CSP) for _ in slaves]
        cycle()
        deadline += 0.001
        while time.perf_counter() < deadline:
            pass
    for _ in range(300):
        cycle()
    out["csp"] = {"worst": worst, "final": [inp(k)[1] for k in range(len(slaves))]}
    outputs[0] = RX.pack(0x0F, 500_000, 0, 0, CSP)
    for _ in range(2000):
        cycle()
        if inp(0)[0] & 0x6F == 0x08:
            break
    out["fault"] = {"sw": inp(0)[0], "error": inp(0)[5]}
    outputs[0] = RX.pack(0x80, 0, 0, 0, CSP)
    for _ in range(10):
        cycle()
    out["reset"] = {"sw": inp(0)[0], "error": inp(0)[5]}
    out["lost"] = lost[0]
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])))
