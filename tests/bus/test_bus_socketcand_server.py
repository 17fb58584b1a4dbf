"""The socketcand server in a rig run in this process (issue 24): BCM mode jobs and subscriptions as
socketcand's doc/protocol.md describes them, bus errors as '< error CLASS t >' (state_raw.c), a client
that never reads is cut off at its backlog while the others get every frame, 127.0.0.1 only."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest
from socketcand_kit import RawClient

from gatewaylab.bus import CanFrame
from gatewaylab.bus.transport.socketcand import SocketcandServer
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig


@pytest.fixture
def rig() -> Iterator[Rig]:
    config = parse_rig({"clock": "realtime", "bus": [{"name": "can0", "socketcand": True, "timing": False,
                                                       "endpoint": "none"}]})
    with Rig(config) as r:
        r.buses["can0"].attach("acker")
        thread = r.run_in_thread()
        yield r
        r.request_stop()
        thread.join(10)


def server(rig: Rig) -> SocketcandServer:
    return rig.socketcand["can0"]


def inject(rig: Rig, *frames: CanFrame) -> None:
    """Frames from a controller inside the rig (sent on the rig thread)."""
    ctrl = rig.buses["can0"].attach("source")

    def send() -> None:
        for frame in frames:
            ctrl.send(frame)

    rig.clock.call_soon_threadsafe(send)


def test_bound_to_loopback_and_listed_in_the_ready_info(rig: Rig) -> None:
    """Issue 24: 127.0.0.1 only; the port is buses.NAME.socketcand in the ready file."""
    assert server(rig).listener.getsockname()[0] == "127.0.0.1"
    assert rig.ready_info()["buses"]["can0"]["socketcand"] == server(rig).port


def test_bcm_subscribe_and_cyclic_add(rig: Rig) -> None:
    """protocol.md 'Mode BCM': nothing is received before a subscription; '< subscribe 0 0 123 >'
    delivers 0x123 as '< frame 123 sec.usec 11 22  >'; '< add 0 10000 ... >' sends every 10 ms until
    '< delete ... >'; '< update ... >' changes the content."""
    listener, bcm = RawClient(server(rig).port), RawClient(server(rig).port)
    try:
        for c in (listener, bcm):
            c.expect(b"< hi >")
            c.send(b"< open can0 >")
            c.expect(b"< ok >")
        listener.send(b"< rawmode >")
        listener.expect(b"< ok >")
        bcm.send(b"< subscribe 0 0 123 >< echo >")
        bcm.expect(b"< echo >")
        inject(rig, CanFrame(0x124, b"\x00"), CanFrame(0x123, b"\x11\x22"))
        seen = bcm.expect(b" >")
        assert seen.startswith(b"< frame 123 ") and seen.endswith(b" 11 22  >")
        bcm.send(b"< add 0 10000 00000456 2 1 2 >")
        listener.expect(b"< frame 00000456 ")
        listener.expect(b" 0102 >")
        bcm.send(b"< update 00000456 1 ff >")
        listener.expect(b" FF >")
        bcm.send(b"< delete 00000456 >< echo >")
        bcm.expect(b"< echo >")
        assert not server(rig).clients[1].jobs
    finally:
        listener.close()
        bcm.close()


def test_bus_off_is_reported_as_an_error_frame(rig: Rig) -> None:
    """state_raw.c: error frames go out as '< error CLASS sec.usec >'; a controller state change to
    bus-off has class CAN_ERR_BUSOFF (0x040, linux/can/error.h)."""
    c = RawClient(server(rig).port)
    try:
        c.open_raw()
        c.send(b"< echo >")
        c.expect(b"< echo >")
        ctrl = server(rig).clients[0].controller
        assert ctrl is not None
        rig.clock.call_soon_threadsafe(rig.buses["can0"].force_bus_off, ctrl)
        assert c.expect(b" >").startswith(b"< error 040 ")
    finally:
        c.close()


def test_a_client_that_never_reads_is_cut_off_and_the_others_get_everything(rig: Rig) -> None:
    """A full socket buffer: the reader that stops reading is disconnected when its backlog passes the
    limit; the rig runs on and a reading client receives all 30000 frames in order."""
    srv = server(rig)
    srv.max_backlog = 64 * 1024
    slow, good = RawClient(srv.port, rcvbuf=4096), RawClient(srv.port)
    try:
        slow.open_raw()
        good.open_raw()
        # the kernel's buffers in between are small, so the backlog grows in the server
        srv.clients[0].sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        count = 30000
        inject(rig, *(CanFrame(0x200, i.to_bytes(2, "big")) for i in range(count)))
        text = good.expect(f" {count - 1:04X} >".encode(), timeout=60)
        values = [int(line.rsplit(b" ", 2)[1], 16) for line in text.split(b"<")[1:]]
        assert values == list(range(count))
        assert any("does not read" in reason for reason in srv.dropped)
        assert len(srv.clients) == 1
    finally:
        slow.close()
        good.close()
