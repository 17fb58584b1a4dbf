"""A listen-only client of the `gatewaylab` interface (issue 14, "Watch": the monitor joins as a listen-only
client: ``can.Bus(interface="gatewaylab", channel=..., listen_only=True)`` never transmits, never
acknowledges and never changes arbitration; sending on it raises ``can.CanOperationError``).
ISO 11898-1 restricted/bus-monitoring mode: the node receives every valid frame and sends nothing, not
even the ACK bit or an error flag."""

import time
from collections.abc import Iterator

import can
import pytest
from can.bus import BusState
from transport_testkit import Rig, drain, one_rig

from gatewaylab.bus import wire


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    yield from one_rig(tmp_path_factory.mktemp("rig"))


def test_hello_carries_the_listen_only_option() -> None:
    """docs/bus-wire.md: HELLO options bit 2 = listen-only; the decoder gives it back, old clients read False."""
    record = wire.encode_hello("mon", listen_only=True)
    (hello,) = wire.RecordDecoder().feed(record)
    assert isinstance(hello, wire.Hello) and hello.listen_only and hello.fd and not hello.receive_own
    (plain,) = wire.RecordDecoder().feed(wire.encode_hello("app"))
    assert isinstance(plain, wire.Hello) and not plain.listen_only
    assert record[4] == 0b110   # options byte after length (2) + type (1) + version (1)


def test_monitor_hears_traffic_and_cannot_send(rig: Rig) -> None:
    """The monitor receives the frames two active nodes exchange; its send() raises CanOperationError and
    its state is PASSIVE (python-can's listen-only state), which cannot be switched to ACTIVE."""
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as a, \
            can.Bus(interface="gatewaylab", channel=rig.endpoint) as b, \
            can.Bus(interface="gatewaylab", channel=rig.endpoint, listen_only=True) as mon:
        assert mon.state is BusState.PASSIVE and a.state is BusState.ACTIVE
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        assert [m.arbitration_id for m in drain(b, 1)] == [0x123]
        heard = drain(mon, 1)
        assert [(m.arbitration_id, bytes(m.data)) for m in heard] == [(0x123, b"\x01\x02")]
        with pytest.raises(can.CanOperationError, match="listen_only"):
            mon.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
        with pytest.raises(can.CanOperationError):
            mon.state = BusState.ACTIVE
        # nothing of the refused send reached the others
        assert drain(b, 1, timeout=0.3) == []


def test_monitor_does_not_acknowledge_a_lone_sender(rig: Rig) -> None:
    """ISO 11898-1 ACK slot: a listen-only node does not acknowledge, so a sender whose only audience is a
    monitor gets ACK errors, goes error-passive, and the monitor never receives that unacknowledged frame."""
    with can.Bus(interface="gatewaylab", channel=rig.endpoint, listen_only=True) as mon, \
            can.Bus(interface="gatewaylab", channel=rig.endpoint, shutdown_timeout=0.2) as lone:
        lone.send(can.Message(arbitration_id=0x321, data=b"\xAA", is_extended_id=False))
        deadline = time.monotonic() + 20
        while lone.controller_state is wire.ControllerStateCode.ERROR_ACTIVE and time.monotonic() < deadline:
            lone.recv(0.05)   # processes the rig's STATUS records
        assert lone.controller_state is wire.ControllerStateCode.ERROR_PASSIVE
        assert [m for m in drain(mon, 1, timeout=0.3) if not m.is_error_frame] == []
