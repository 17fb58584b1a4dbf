"""Fixtures of the CANopen tests: a simulated clock, a virtual bus, nodes and a python-canopen client.

Other test modules of this folder may append fixtures below; keep names distinct.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import canopen
import pytest
from canopen_testkit import RawClient, Sniffer, sample_od

from gatewaylab.bus import VirtualBus, python_can_bus
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.od import ObjectDictionary


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


@pytest.fixture
def vbus(clock: SimulatedClock) -> VirtualBus:
    return VirtualBus(clock, "can0", bitrate=1_000_000)


@pytest.fixture
def make_node(clock: SimulatedClock, vbus: VirtualBus) -> Callable[..., Node]:
    """``make_node(node_id=5, od=None, start=True, **kwargs)`` -> a started Node on ``vbus``."""

    def make(node_id: int | None = 5, od: ObjectDictionary | None = None, start: bool = True,
             **kwargs: Any) -> Node:
        node = Node(clock, vbus, node_id, od if od is not None else sample_od(), **kwargs)
        if start:
            with clock.lock:
                node.start()        # the boot-up goes out once another controller acknowledges it
        return node

    return make


@pytest.fixture
def network(vbus: VirtualBus) -> Iterator[canopen.Network]:
    """A python-canopen network on the virtual bus (the independent client)."""
    net = canopen.Network(python_can_bus(vbus, name="python-canopen"))
    net.NOTIFIER_CYCLE = 0.01       # the notifier thread's recv timeout: a quick disconnect
    net.connect()
    try:
        yield net
    finally:
        net.disconnect()


@pytest.fixture
def sniffer(vbus: VirtualBus) -> Sniffer:
    return Sniffer(vbus)


@pytest.fixture
def raw(clock: SimulatedClock, vbus: VirtualBus) -> RawClient:
    return RawClient(clock, vbus)
