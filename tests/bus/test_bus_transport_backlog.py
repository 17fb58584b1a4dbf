"""A `gatewaylab` client that does not read (issue 21, the user's path): as a full SocketCAN receive
queue does, the rig drops the frames it would receive -- counted, one log line -- and keeps the client:
its own frames still go out and are acknowledged, and once it reads it gets frames again; a client that
reads gets every frame in order meanwhile (docs/bus-wire.md)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import can
import pytest

from gatewaylab.bus import CanFrame
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

COUNT = 20_000


@pytest.fixture
def rig() -> Iterator[Rig]:
    # bit timing on (250 kbit/s, ~3,500 of these frames a second): a reading client keeps up, as on a real
    # bus, even a pure-Python one on a loaded 2-CPU machine (at 1 Mbit/s, ~14,000 frames a second, the
    # reading client of a loaded `make test` fell behind for good and lost frames too)
    config = parse_rig({"clock": "realtime", "bus": [{"name": "can0", "bitrate": 250_000}]})
    with Rig(config) as r:
        r.servers["can0"].max_backlog = 16 * 1024   # before any client connects (each takes it then)
        r.buses["can0"].attach("acker")
        thread = r.run_in_thread()
        yield r
        r.request_stop()
        thread.join(10)


def inject(rig: Rig, frames: list[CanFrame]) -> None:
    """Frames from a controller inside the rig, sent on the rig thread."""
    ctrl = rig.buses["can0"].attach("source")

    def send() -> None:
        for frame in frames:
            ctrl.send(frame)

    rig.clock.call_soon_threadsafe(send)


def receive(bus: can.BusABC, until: int, seconds: float) -> list[int]:
    """The values of 0x200 frames received until ``until`` came or ``seconds`` passed with none."""
    values: list[int] = []
    while (msg := bus.recv(seconds)) is not None:
        if msg.arbitration_id == 0x200:
            values.append(int.from_bytes(msg.data, "big"))
            if values[-1] == until:
                break
    return values


def test_a_client_that_does_not_read_loses_frames_not_its_connection(rig: Rig) -> None:
    server = rig.servers["can0"]
    endpoint = server.endpoint
    with can.Bus(interface="gatewaylab", channel=endpoint) as slow, \
         can.Bus(interface="gatewaylab", channel=endpoint) as good:
        inject(rig, [CanFrame(0x200, i.to_bytes(3, "big")) for i in range(COUNT)])
        assert receive(good, COUNT - 1, 10) == list(range(COUNT))      # the reading client: all, in order
        deadline = time.monotonic() + 10
        while server.rx_dropped == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert server.rx_dropped > 0
        assert not any("does not read" in reason for reason in server.dropped)   # still connected
        slow.send(can.Message(arbitration_id=0x321, data=b"\x01", is_extended_id=False), timeout=5)
        assert good.recv(10) is not None                                # its frame went out
        got = receive(slow, COUNT - 1, 0.5)
        assert 0 < len(got) < COUNT and got == sorted(got) and got[0] == 0   # what fitted, in order
        inject(rig, [CanFrame(0x200, (COUNT + i).to_bytes(3, "big")) for i in range(10)])
        assert receive(slow, COUNT + 9, 10)[-10:] == list(range(COUNT, COUNT + 10))   # it reads again
