"""SOEM (pysoem) over a veth pair drives the ECAN-Lite as manual 5.4.3 / 5.4.4.1 tell a third-party
master to: phases A-D over CoE, the first N chunks assigned, OP, the manual's frame on CAN0 and the
frames of a CAN peer in the TxPDO (N = 1, 3, 8; N = 24 exceeds SOEM's 4096 B IO map and runs in process)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import can
import pytest

from gatewaylab.bus import VirtualBus, python_can_bus
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

pytestmark = [pytest.mark.net, pytest.mark.slow]


@pytest.mark.parametrize("n", [1, 3, 8])
def test_soem_bring_up_and_the_manual_frame(veth_ns: Any, tmp_path: Path, n: int) -> None:
    """5.4.3 A-D: capability reads (>= 4 channels, N range, 128 B unit, 24 B header); D readback status 0,
    128*N bytes, 128*N-24 frame area, profile word (N-1) | 0x0F << 5; SOEM's config_map gets 128*N each
    way and OP; 5.4.4.1: `40 00 23 01 11 22 33 44 55 66 77 88` at offset 24 reaches CAN0 as 0x123; a
    peer's frame on CAN1 arrives in the TxPDO; no working-counter error, no PDO error."""
    clock = RealTimeClock()
    buses = [VirtualBus(clock, f"can{i}", 1_000_000, 5_000_000) for i in range(4)]
    device = EcanLiteDevice(clock, [b.attach(f"mcan{i}") for i, b in enumerate(buses)], flash_path=tmp_path / "f")
    wire = WireTransport(Segment([device.slave]), veth_ns.emulator_iface, clock, drive_clock=True)
    wire.start()
    c0 = python_can_bus(buses[0])
    c1 = python_can_bus(buses[1])

    def peer() -> None:
        """The peer on CAN1 talks once the master has the device in OP (its channel applied)."""
        if device.slave.state == AlState.OP:
            c1.send(can.Message(arbitration_id=0x2A5, data=b"peer", is_extended_id=False))
        else:
            clock.call_later(0.002, peer)

    clock.call_soon(peer)
    try:
        proc = veth_ns.run_master("bringup", str(n), "300")
    finally:
        wire.stop()
    try:
        assert proc.returncode == 0, proc.stderr[-3000:]
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        assert r["count"] == 1 and r["name"] == "ECAN-Lite" and r["name_1008"] == "ECAN-Lite"
        a = r["A"]
        assert a["channels"] >= 4 and a["n_min"] <= n <= a["n_max"] and a["profiles"] & 1
        assert (a["unit"], a["header"]) == (128, 24)
        word = (n - 1) | 0x0F << 5
        assert r["D"] == {"0x8010": [0, 128 * n, 128 * n - 24, word], "0x8011": [0, 128 * n, 128 * n - 24, word]}
        assert r["E"] == [0, 0, 0, 0]  # phase E: 1 Mbit/s + 5 Mbit/s FD, 87.5 %, applied
        assert r["op"] == 8 and r["sizes"] == [128 * n, 128 * n]
        assert r["bad_wkc"] == 0 and r["tx_errors"] == []
        assert [1, 0x2A5, b"peer".hex()] in r["rx_packets"]
        assert (r["last_pdo_error"], r["pdo_errors"]) == (0, 0)
        msg = c0.recv(0)
        assert msg is not None and (msg.arbitration_id, bytes(msg.data)) == (0x123, bytes.fromhex("1122334455667788"))
        assert c0.recv(0) is None  # the master repeated the same image: an idempotent no-op (13.8)
        assert not wire.errors
    finally:
        c0.shutdown()
        c1.shutdown()

