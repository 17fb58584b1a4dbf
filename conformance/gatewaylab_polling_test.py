"""`make conformance`'s own check of the polling loops every python-can program writes (issue 21): a cyclic
task draining with ``while (msg := bus.recv(0)) is not None`` and a ``recv(timeout)`` loop, on the
``gatewaylab`` interface against the conformance rig. python-can's ``virtual`` interface returns every frame
to both loops; so must this one (``recv(0)`` returned nothing, forever, before issue 21).

Run by ``conformance/run.py`` beside python-can's and canopen's suites (the rig from its ready file,
GATEWAYLAB_CONFORMANCE_READY); ``pytest conformance/gatewaylab_polling_test.py`` alone starts its own rig.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from gatewaylab.rig.process import RigProcess

COUNT = 100
DEADLINE = 20.0     # an end to waiting, never a timing assert


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    """The last bus of the conformance rig (the suites take theirs first come, first served)."""
    ready = os.environ.get("GATEWAYLAB_CONFORMANCE_READY")
    if ready:
        buses = json.loads(Path(ready).read_text())["buses"]
        yield str(buses[sorted(buses)[-1]]["endpoint"])
        return
    with tempfile.TemporaryDirectory() as tmp:
        rig_file = Path(tmp) / "rig.toml"
        rig_file.write_text('clock = "realtime"\n[[bus]]\nname = "can0"\nbitrate = 1000000\n')
        with RigProcess(rig_file, workdir=tmp, timeout=60) as rig:
            yield rig.endpoint("can0")


def _send_all(endpoint: str, can_id: int) -> None:
    with can.Bus(interface="gatewaylab", channel=endpoint) as tx:
        for i in range(COUNT):
            tx.send(can.Message(arbitration_id=can_id, data=i.to_bytes(2, "little"), is_extended_id=False))


def _numbers(got: list[can.Message], can_id: int) -> list[int]:
    return [int.from_bytes(m.data, "little") for m in got if m.arbitration_id == can_id]


def test_recv_zero_poll_loop_of_a_cyclic_task(endpoint: str) -> None:
    """python-can BusABC.recv: timeout 0 returns a frame that has arrived, without waiting."""
    got: list[can.Message] = []
    with can.Bus(interface="gatewaylab", channel=endpoint) as rx:
        sender = threading.Thread(target=_send_all, args=(endpoint, 0x5A0))
        sender.start()
        deadline = time.monotonic() + DEADLINE
        while len(_numbers(got, 0x5A0)) < COUNT and time.monotonic() < deadline:
            while (msg := rx.recv(0)) is not None:      # the cyclic task's drain
                got.append(msg)
            time.sleep(0.002)                           # its period
        sender.join(DEADLINE)
    assert _numbers(got, 0x5A0) == list(range(COUNT))


def test_recv_timeout_loop(endpoint: str) -> None:
    """python-can BusABC.recv(timeout): every frame, in order, each within the timeout."""
    got: list[can.Message] = []
    with can.Bus(interface="gatewaylab", channel=endpoint) as rx:
        sender = threading.Thread(target=_send_all, args=(endpoint, 0x5A1))
        sender.start()
        while len(_numbers(got, 0x5A1)) < COUNT:
            msg = rx.recv(2.0)
            if msg is None:
                break
            got.append(msg)
        sender.join(DEADLINE)
    assert _numbers(got, 0x5A1) == list(range(COUNT))
