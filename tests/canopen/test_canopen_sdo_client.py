"""Our sans-I/O SdoClient against our Node and against python-canopen's LocalNode (a server we did not write).

Manual: IDX Communication Guide 3.3.3.2 and table 6-20; CiA 301 7.2.4.
"""

from __future__ import annotations

import threading
from typing import Any

import canopen

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.sdo_client import SdoClient
from gatewaylab.od import SdoAbort, SdoAbortCode


class Harness:
    def __init__(self, clock: Any, vbus: Any, timeout: float = 0.5) -> None:
        self.clock = clock
        self.vbus = vbus
        self.results: list[Any] = []
        self.ctrl = vbus.attach("sdo-client", on_frame=self._on_frame)
        self.client = SdoClient(clock, self.ctrl.send, timeout=timeout)

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        self.client.on_frame(frame, t)

    def run(self) -> None:
        with self.clock.lock:
            self.clock.run_while(lambda: self.vbus.busy)

    def upload(self, node_id: int, index: int, sub: int, **kw: Any) -> Any:
        self.client.upload(node_id, index, sub, self.results.append, **kw)
        self.run()
        return self.results.pop()

    def download(self, node_id: int, index: int, sub: int, data: bytes, **kw: Any) -> Any:
        self.client.download(node_id, index, sub, data, self.results.append, **kw)
        self.run()
        return self.results.pop()


def test_client_expedited_segmented_block(clock, vbus, make_node) -> None:
    """CiA 301 7.2.4: every transfer type reads and writes the same values as the server holds."""
    node = make_node()
    h = Harness(clock, vbus)
    assert h.upload(5, 0x2000, 0) == (0x12345678).to_bytes(4, "little")
    assert h.upload(5, 0x2001, 0) == b"gatewaylab CANopen node"
    assert h.upload(5, 0x2002, 0, block=True) == bytes(range(256)) * 4
    assert h.download(5, 0x2011, 0, b"\x22\x11") is None
    assert node.get(0x2011) == 0x1122
    assert h.download(5, 0x2000, 0, b"\x01\x00\x00\x00", segmented=True) is None
    assert node.get(0x2000) == 1
    assert h.download(5, 0x2002, 0, bytes(1500), block=True) is None
    assert node.get(0x2002) == bytes(1500)
    assert h.download(5, 0x2001, 0, b"") is None
    assert node.get(0x2001) == ""
    assert h.upload(5, 0x2001, 0) == b""
    assert h.upload(5, 0x2001, 0, block=True) == b""


def test_client_reports_server_aborts(clock, vbus, make_node) -> None:
    """IDX table 6-20: the server's abort code reaches the callback unchanged."""
    make_node()
    h = Harness(clock, vbus)
    assert h.upload(5, 0x3000, 0) == SdoAbort(SdoAbortCode.OBJECT_DOES_NOT_EXIST)
    assert h.download(5, 0x2004, 0, b"\x01") == SdoAbort(SdoAbortCode.READ_ONLY)
    assert h.download(5, 0x2002, 0, b"x" * 20, block=True) is None
    assert h.upload(5, 0x2005, 0, block=True) == SdoAbort(SdoAbortCode.WRITE_ONLY)


def test_client_timeout_sends_abort(clock, vbus, make_node) -> None:
    """IDX table 6-20 0x05040000: no answer within the timeout -> callback and an abort frame to the server."""
    h = Harness(clock, vbus, timeout=0.5)
    seen: list[CanFrame] = []
    vbus.add_monitor(lambda f, t: seen.append(f))
    vbus.attach("acker")                     # someone acknowledges frames, nobody answers
    h.client.upload(9, 0x1000, 0, h.results.append)
    clock.advance(0.49)
    assert h.results == []
    clock.advance(0.02)
    assert h.results == [SdoAbort(SdoAbortCode.SDO_PROTOCOL_TIMED_OUT)]
    assert seen[-1].can_id == 0x609 and seen[-1].data == bytes([0x80, 0x00, 0x10, 0x00, 0, 0, 4, 5])


def test_client_queues_one_transfer_per_node(clock, vbus, make_node) -> None:
    """Contract: one transfer per server node at a time, the others wait their turn."""
    node = make_node()
    make_node(node_id=6)
    h = Harness(clock, vbus)
    order: list[str] = []
    h.client.upload(5, 0x2001, 0, lambda r: order.append(f"a:{r!r}"))
    h.client.download(5, 0x2001, 0, b"second", lambda r: order.append(f"b:{r!r}"))
    h.client.upload(5, 0x2001, 0, lambda r: order.append(f"c:{r!r}"))
    h.client.upload(6, 0x2004, 0, lambda r: order.append(f"d:{r!r}"))
    assert h.client.busy(5) and h.client.busy(6)
    h.run()
    assert [o for o in order if o[0] in "abc"] == ["a:b'gatewaylab CANopen node'", "b:None", "c:b'second'"]
    assert "d:b'*'" in order
    assert node.get(0x2001) == "second"
    assert not h.client.busy(5)


def test_client_against_python_canopen_local_node(clock, vbus, network) -> None:
    """Interop: our client reads and writes python-canopen's LocalNode (expedited and segmented)."""
    od = canopen.ObjectDictionary()
    var = canopen.objectdictionary.ODVariable("Value", 0x2000, 0)
    var.data_type = canopen.objectdictionary.UNSIGNED32
    var.access_type = "rw"
    var.default = 0x0A0B0C0D
    od.add_object(var)
    text = canopen.objectdictionary.ODVariable("Text", 0x2001, 0)
    text.data_type = canopen.objectdictionary.VISIBLE_STRING
    text.access_type = "rw"
    text.default = "a text longer than four bytes"
    od.add_object(text)
    local = canopen.LocalNode(7, od)
    network.add_node(local)
    h = Harness(clock, vbus, timeout=5.0)
    got: list[Any] = []
    done = threading.Event()

    def cb(result: Any) -> None:
        got.append(result)
        done.set()

    # LocalNode answers from canopen's notifier thread; its send() runs the simulation, which
    # carries our follow-up requests too. We only put the first request on the wire.
    for action in (lambda: h.client.upload(7, 0x2000, 0, cb),
                   lambda: h.client.upload(7, 0x2001, 0, cb),
                   lambda: h.client.download(7, 0x2001, 0, b"written by gatewaylab", cb)):
        done.clear()
        with clock.lock:
            action()
        h.run()
        assert done.wait(5.0)
    assert got[0] == (0x0A0B0C0D).to_bytes(4, "little")
    assert got[1] == b"a text longer than four bytes"
    assert got[2] is None
    assert local.sdo[0x2001].raw == "written by gatewaylab"
