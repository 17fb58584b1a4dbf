"""Helpers shared by the CANopen tests (imported by conftest.py and the test modules)."""

from __future__ import annotations

import io
import threading
from collections.abc import Callable
from typing import Any

import canopen

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.od import Access, DataType, ObjectDictionary


def sample_od() -> ObjectDictionary:
    """A small application dictionary covering the data types and access rights of CiA 301."""
    od = ObjectDictionary()
    od.add_variable(0x2000, "U32 rw", DataType.UNSIGNED32, Access.RW, 0x12345678, pdo_mappable=True)
    od.add_variable(0x2001, "String rw", DataType.VISIBLE_STRING, Access.RW, "gatewaylab CANopen node",
                    max_length=64)
    od.add_variable(0x2002, "Domain rw", DataType.DOMAIN, Access.RW, bytes(range(256)) * 4)
    od.add_variable(0x2003, "I16 limited", DataType.INTEGER16, Access.RW, 0, low=-100, high=100,
                    pdo_mappable=True)
    od.add_variable(0x2004, "U8 ro", DataType.UNSIGNED8, Access.RO, 42, pdo_mappable=True)
    od.add_variable(0x2005, "U32 wo", DataType.UNSIGNED32, Access.WO, 0, pdo_mappable=True)
    od.add_variable(0x2006, "U16 const", DataType.UNSIGNED16, Access.CONST, 0xBEEF)
    od.add_variable(0x2007, "I32 rw", DataType.INTEGER32, Access.RW, -5, pdo_mappable=True)
    od.add_variable(0x2008, "REAL32", DataType.REAL32, Access.RW, 1.5, pdo_mappable=True)
    od.add_variable(0x2009, "REAL64", DataType.REAL64, Access.RW, -2.25)
    od.add_variable(0x200A, "U64", DataType.UNSIGNED64, Access.RW, 2**63 + 5, pdo_mappable=True)
    od.add_variable(0x200B, "I8", DataType.INTEGER8, Access.RW, -1, pdo_mappable=True)
    od.add_variable(0x200C, "BOOLEAN", DataType.BOOLEAN, Access.RW, True, pdo_mappable=True)
    od.add_variable(0x200D, "Octets", DataType.OCTET_STRING, Access.RW, b"\x01\x02\x03\x04\x05\x06")
    od.add_variable(0x200E, "U24", DataType.UNSIGNED24, Access.RW, 0x123456)
    od.add_variable(0x200F, "I48", DataType.INTEGER48, Access.RW, -(2**40))
    od.add_variable(0x2010, "U16 pre-op only", DataType.UNSIGNED16, Access.RW, 7, preop_only=True)
    od.add_variable(0x2011, "U16 rw", DataType.UNSIGNED16, Access.RW, 0x1111, pdo_mappable=True)
    od.add_array(0x2100, "U16 array", DataType.UNSIGNED16, 3, Access.RW, 0x55, pdo_mappable=True)
    od.add_record(0x2200, "Record")
    od.add_sub(0x2200, 1, "First", DataType.UNSIGNED8, Access.RW, 1)
    od.add_sub(0x2200, 3, "Third", DataType.INTEGER32, Access.RO, -3)
    od.add_variable(0x6000, "U8 application", DataType.UNSIGNED8, Access.RW, 3)
    return od


def remote_for(network: canopen.Network, node: Node) -> canopen.RemoteNode:
    """A canopen RemoteNode whose dictionary is our node's exported EDS."""
    stream = io.StringIO(node.to_eds())
    stream.name = f"{node.name}.eds"
    assert node.node_id is not None
    remote = canopen.RemoteNode(node.node_id, stream)
    network.add_node(remote)
    return remote


def barrier(remote: canopen.RemoteNode) -> None:
    """One SDO round trip: every frame queued before it has been processed by canopen's notifier."""
    remote.sdo.upload(0x1000, 0)


def while_waiting(condition: threading.Condition, wait: Callable[[], Any],
                  action: Callable[[], Any]) -> Any:
    """Run ``action`` (advance the clock) in a thread while ``wait`` blocks on ``condition``.

    Holding ``condition`` first makes sure the waiter is waiting before anything is notified.
    """
    with condition:
        worker = threading.Thread(target=action)
        worker.start()
        result = wait()
    worker.join()
    return result


class Sniffer:
    """Records every frame that completes on the bus with its end time."""

    def __init__(self, vbus: VirtualBus) -> None:
        self.frames: list[tuple[float, CanFrame]] = []
        vbus.add_monitor(self._on)

    def _on(self, frame: CanFrame, t: float) -> None:
        self.frames.append((t, frame))

    def ids(self, can_id: int) -> list[tuple[float, CanFrame]]:
        return [(t, f) for t, f in self.frames if f.can_id == can_id]

    def clear(self) -> None:
        self.frames.clear()


class RawClient:
    """A bare controller that sends frames and collects what it receives, for exact-frame tests."""

    def __init__(self, clock: SimulatedClock, vbus: VirtualBus) -> None:
        self.clock = clock
        self.vbus = vbus
        self.received: list[CanFrame] = []
        self.ctrl = vbus.attach("raw-client", on_frame=lambda f, t: self.received.append(f))

    def send(self, can_id: int, data: bytes | list[int] = b"", *, rtr: bool = False, dlc: int = -1) -> None:
        with self.clock.lock:
            self.ctrl.send(CanFrame(can_id, bytes(data), rtr=rtr, dlc=dlc))
            self.clock.run_while(lambda: self.vbus.busy)

    def sdo(self, node_id: int, data: bytes | list[int]) -> bytes | None:
        """Send one SDO request; the node's answer (or None when it stays silent)."""
        self.received.clear()
        self.send(0x600 + node_id, bytes(data).ljust(8, b"\x00") if len(data) <= 8 else bytes(data))
        answers = [f.data for f in self.received if f.can_id == 0x580 + node_id]
        assert len(answers) <= 1, answers
        return answers[0] if answers else None

    def push(self, node_id: int, data: bytes | list[int]) -> None:
        """Send one SDO request padded to 8 bytes without looking at the answers."""
        self.send(0x600 + node_id, bytes(data).ljust(8, b"\x00"))

    def take(self, can_id: int) -> list[CanFrame]:
        got = [f for f in self.received if f.can_id == can_id]
        self.received = [f for f in self.received if f.can_id != can_id]
        return got
