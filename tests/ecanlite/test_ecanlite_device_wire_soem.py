"""SOEM (pysoem) over a veth pair drives the ECAN-Lite as manual 5.4.3 / 5.4.4.1 tell a third-party
master to: phases A-D over CoE, the first N chunks assigned, OP, the manual's frame on CAN0 and the
frames of a CAN peer in the TxPDO (N = 1, 3, 8; N = 24 exceeds SOEM's 4096 B IO map and runs in process)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

pytestmark = [pytest.mark.net, pytest.mark.slow]


SIZES = (1, 3, 8)


def test_soem_bring_up_and_the_manual_frame(veth_ns: Any, tmp_path: Path) -> None:
    """5.4.3 A-D: capability reads (>= 4 channels, N range, 128 B unit, 24 B header); D readback status 0,
    128*N bytes, 128*N-24 frame area, profile word (N-1) | 0x0F << 5; E applied; SOEM's config_map gets
    128*N each way and OP; 5.4.4.1: `40 00 23 01 11 22 33 44 55 66 77 88` at offset 24 reaches CAN0 as
    0x123; a peer's frame on CAN1 arrives in the TxPDO; no working-counter error, no PDO error. N = 1,
    3, 8 in turn, each from a fresh SOEM scan, the device switching size as 14.2 says."""
    clock = RealTimeClock()
    buses = [VirtualBus(clock, f"can{i}", 1_000_000, 5_000_000) for i in range(4)]
    device = EcanLiteDevice(clock, [b.attach(f"mcan{i}") for i, b in enumerate(buses)], flash_path=tmp_path / "f")
    wire = WireTransport(Segment([device.slave]), veth_ns.emulator_iface, clock, drive_clock=True)
    heard: list[tuple[int, bytes]] = []
    buses[0].attach("peer0", on_frame=lambda f, t: heard.append((f.can_id, f.data)))
    c1 = buses[1].attach("peer1")
    was_op = [False]

    def peer() -> None:
        """The peer on CAN1 talks once each time the master has the device in OP (channel applied)."""
        op = device.slave.state == AlState.OP
        if op and not was_op[0]:
            c1.send(CanFrame(0x2A5, b"peer"))
        was_op[0] = op
        clock.call_later(0.002, peer)

    clock.call_soon(peer)
    wire.start()
    try:
        proc = veth_ns.run_master("bringup", ",".join(str(n) for n in SIZES), "300")
    finally:
        wire.stop()
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    print("SDO accesses retried after a lost mailbox frame:", r["retries"])
    assert r["count"] == 1 and r["name"] == "ECAN-Lite" and r["name_1008"] == "ECAN-Lite"
    for n in SIZES:
        s = r[str(n)]
        a = s["A"]
        assert a["channels"] >= 4 and a["n_min"] <= n <= a["n_max"] and a["profiles"] & 1
        assert (a["unit"], a["header"]) == (128, 24)
        word = (n - 1) | 0x0F << 5
        assert s["D"] == {"0x8010": [0, 128 * n, 128 * n - 24, word], "0x8011": [0, 128 * n, 128 * n - 24, word]}
        assert s["E"] == [0, 0, 0, 0]  # phase E: 1 Mbit/s + 5 Mbit/s FD, 87.5 %, applied
        assert s["op"] == 8 and s["sizes"] == [128 * n, 128 * n]
        assert s["bad_wkc"] == 0 and s["tx_errors"] == []
        assert [1, 0x2A5, b"peer".hex()] in s["rx_packets"]
        assert (s["last_pdo_error"], s["pdo_errors"]) == (0, 0)
    # the frame once per size: the master repeated each image, an idempotent no-op (13.8)
    assert heard == [(0x123, bytes.fromhex("1122334455667788"))] * len(SIZES)
    assert not wire.errors
