"""maxon IDX USB command protocol: ReadObject transactions per second over the pseudo-terminal.

A real-time rig (1 Mbit/s bus) runs the IDX (node 1) and one drive (node 2) in its loop thread;
the host client in this thread talks pyserial to the pty. Measured: ReadObject of a local object
and of node 2 through the gateway (an SDO round trip on the bus), median and p99 latency. The
baseline is a bare pty responder in the same loop that answers every request with the guide's
fixed response bytes without decoding anything: what the pty and the loop alone cost.
Targets: >= 3,000/s local, >= 1,000/s through the gateway. Printed, never asserted.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.hosts.maxon_idx.client import IdxClient
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

N_LOCAL = 3000
N_GATEWAY = 1500
GUIDE_REQUEST = bytes([0x90, 0x02, 0x60, 0x02, 0x01, 0xB0, 0x30, 0x00, 0x2E, 0x62])
GUIDE_RESPONSE = bytes([0x90, 0x02, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x01, 0x90, 0x90, 0x00, 0x00,
                        0x9A, 0x5C])


def _rig() -> tuple[Rig, Drive]:
    rig = Rig(parse_rig({
        "clock": "realtime",
        "bus": [{"name": "can0", "bitrate": 1_000_000, "endpoint": "none"}],
        "device": [{"kind": "maxon_idx", "name": "idx1", "bus": "can0", "node_id": 1, "serial": 0x2001,
                    "usb": {"pty": True}}],
    }), clock=RealTimeClock(), endpoints=False)
    with rig.clock.lock:
        drive = Drive(rig.clock, rig.buses["can0"], 2, 0x1002, "drive2")
        drive.start()
        rig.start()
    return rig, drive


def _measure(call: Callable[[], object], n: int) -> tuple[float, float, float]:
    """(transactions/s, median ms, p99 ms)."""
    for _ in range(50):
        call()
    lat = []
    t0 = time.perf_counter()
    for _ in range(n):
        t = time.perf_counter()
        call()
        lat.append(time.perf_counter() - t)
    total = time.perf_counter() - t0
    lat.sort()
    return n / total, statistics.median(lat) * 1e3, lat[int(0.99 * (n - 1))] * 1e3


def _baseline(rig: Rig) -> tuple[float, float, float]:
    """Bare pty echo of the guide's response in the same loop: transport + loop cost only."""
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    os.set_blocking(master, False)

    def on_readable() -> None:
        data = os.read(master, 4096)
        for _ in range(data.count(0x62)):       # one reply per request (request ends in 0x62)
            os.write(master, GUIDE_RESPONSE)

    with rig.clock.lock:
        rig.add_reader(master, on_readable)
    rig.wake()
    import serial

    port = serial.Serial(os.ttyname(slave), timeout=1)

    def call() -> None:
        port.write(GUIDE_REQUEST)
        if len(port.read(len(GUIDE_RESPONSE))) != len(GUIDE_RESPONSE):
            raise RuntimeError("baseline responder did not answer")

    try:
        return _measure(call, N_LOCAL)
    finally:
        port.close()
        with rig.clock.lock:
            rig.remove_reader(master)
        os.close(master)
        os.close(slave)


def main() -> None:
    rig, drive = _rig()
    thread = rig.run_in_thread()
    try:
        path = rig.ready_info()["usb"]["idx1"]["pty"]
        base = _baseline(rig)
        with IdxClient(path, timeout=2.0) as client:
            local = _measure(lambda: client.read_object(1, 0x30B0, 0), N_LOCAL)
            gateway = _measure(lambda: client.read_object(2, 0x6041, 0), N_GATEWAY)
        print(f"{'ReadObject over the pty':38s} {'tx/s':>9s} {'median ms':>10s} {'p99 ms':>8s} {'vs baseline':>12s}")
        for name, (rate, med, p99), target in (
                ("baseline: bare pty responder", base, None),
                ("local object (node 1, 0x30B0)", local, 3000),
                ("gateway to node 2 (SDO on 1 Mbit/s)", gateway, 1000)):
            ratio = rate / base[0]
            goal = "" if target is None else f"  target >= {target}/s: {'met' if rate >= target else 'NOT met'}"
            print(f"{name:38s} {rate:9.0f} {med:10.3f} {p99:8.3f} {ratio:11.2f}x{goal}")
    finally:
        rig.request_stop()
        thread.join(5)
        with rig.clock.lock:
            drive.stop()
        rig.close()


if __name__ == "__main__":
    main()
