"""The hand-over between pymodbus's server thread and the rig thread (docs/architecture.md "Threads"):
several PLCs at once, each request answered with its own node's value, none lost or mixed up."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest
from pymodbus.client import ModbusTcpClient

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.rig import Rig
from gatewaylab.rig.config import parse_rig

SERIALS = {2: 0x1002, 3: 0x1003, 4: 0x1004}


@pytest.fixture
def port() -> Iterator[int]:
    rig = Rig(parse_rig({
        "clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}],
        "drive": [{"bus": "can0", "node_id": n, "serial": s} for n, s in SERIALS.items()],
        "device": [{"kind": "modbus_gateway", "name": "mb", "bus": "can0", "node_id": 100, "nodes": [2, 3, 4],
                    "map": [{"register": 0, "kind": "input", "index": 0x1018, "subindex": 4, "type": "u32"},
                            {"register": 0, "kind": "holding", "index": 0x607A, "type": "i32"}]}]}),
        clock=RealTimeClock(), endpoints=False)
    rig.start()
    thread = rig.run_in_thread()
    try:
        yield int(rig.ready_info()["modbus"]["mb"].rsplit(":", 1)[1])
    finally:
        rig.request_stop()
        thread.join(10)
        rig.close()


def test_concurrent_clients_get_their_own_answers(port: int) -> None:
    """Modbus TCP (MBAP transaction ids per connection): three clients, each writing and reading back
    its own value to its own node while the others do the same, 100 rounds each; every read of the
    identity object 0x1018:04 returns that node's serial (input registers 0-1, high word first)."""
    errors: list[Any] = []

    def plc(node: int) -> None:
        try:
            with ModbusTcpClient("127.0.0.1", port=port, timeout=5) as c:
                for k in range(100):
                    value = node * 1000 + k
                    w = c.write_registers(0, [value >> 16, value & 0xFFFF], device_id=node)
                    r = c.read_holding_registers(0, count=2, device_id=node)
                    s = c.read_input_registers(0, count=2, device_id=node)
                    if w.isError() or r.registers != [value >> 16, value & 0xFFFF] or \
                            s.registers != [SERIALS[node] >> 16, SERIALS[node] & 0xFFFF]:
                        errors.append((node, k, w, r, s))
                        return
        except Exception as exc:
            errors.append((node, exc))

    threads = [threading.Thread(target=plc, args=(n,)) for n in SERIALS]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors[:3]
    assert not any(t.is_alive() for t in threads)
