"""Issue 15 "Frames lost on close": every frame `send()` accepted reaches the bus, even when the
client closes at once; the transmit queue is bounded like a SocketCAN device's (docs/bus-wire.md
"Transmit queue and closing")."""

import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest
from transport_testkit import Rig, drain, one_rig, rigs

from gatewaylab.bus import CanFrame, wire


@pytest.fixture
def rig_factory(tmp_path: Path) -> Iterator[Callable[..., Rig]]:
    yield from rigs(tmp_path)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    """One rig for the tests whose clients leave nothing queued (the others start their own)."""
    yield from one_rig(tmp_path_factory.mktemp("rig"))


def test_thousand_frames_then_shutdown_all_arrive(rig: Rig) -> None:
    """Issue 15: 1,000 frames to a 1 Mbit/s bus, then shutdown(): a second client counts 1,000, in order
    (before the fix about 10 % arrived)."""
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as listener:
        sender = can.Bus(interface="gatewaylab", channel=rig.endpoint)
        for i in range(1000):
            sender.send(can.Message(arbitration_id=0x100, data=i.to_bytes(2, "little"), is_extended_id=False))
        sender.shutdown()
        got = drain(listener, 1000)
    assert [int.from_bytes(m.data, "little") for m in got] == list(range(1000))


def test_frames_of_a_client_that_vanishes_are_still_transmitted(rig: Rig) -> None:
    """Issue 15: "the server keeps transmitting a departed client's queue": a raw client writes HELLO and
    300 FRAME records (docs/bus-wire.md) and closes without waiting; all 300 reach the bus."""
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as listener:
        raw = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        raw.connect(rig.endpoint[len("unix:"):])
        raw.sendall(wire.encode_hello("vanishing") + b"".join(
            wire.encode_frame(CanFrame(0x200, i.to_bytes(2, "little"))) for i in range(300)))
        raw.close()
        got = drain(listener, 300)
    assert [int.from_bytes(m.data, "little") for m in got] == list(range(300))


def test_can_player_replays_a_10000_frame_log_in_order(rig: Rig, tmp_path: Path) -> None:
    """Issue 15: `python -m can.player` replaying a 10,000-frame log at full speed against `gatewaylab run`:
    a listener counts 10,000, in order."""
    log = tmp_path / "replay.log"
    with can.Logger(str(log)) as writer:
        for i in range(10_000):
            writer(can.Message(timestamp=1_700_000_000 + i * 1e-4, arbitration_id=0x123,
                               data=i.to_bytes(4, "little"), is_extended_id=False))
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as listener:
        player = subprocess.run([sys.executable, "-m", "can.player", "-i", "gatewaylab", "-c", rig.endpoint,
                                 "--ignore-timestamps", str(log)], capture_output=True, text=True, timeout=120)
        assert player.returncode == 0, player.stderr
        got = drain(listener, 10_000)
    assert len(got) == 10_000
    assert [int.from_bytes(m.data, "little") for m in got] == list(range(10_000))


def test_full_transmit_queue_blocks_then_raises(rig_factory) -> None:
    """Issue 15: the TX queue is bounded like a SocketCAN device's: when it is full, send(msg, timeout) waits
    up to timeout, then raises can.CanOperationError (a lone node: nobody acknowledges, docs/bus.md "A lone
    node")."""
    rig = rig_factory()
    with can.Bus(interface="gatewaylab", channel=rig.endpoint, tx_queue_len=4, shutdown_timeout=0.5) as lone:
        for i in range(4):
            lone.send(can.Message(arbitration_id=0x300 + i, is_extended_id=False), timeout=5.0)
        with pytest.raises(can.CanOperationError, match=r"transmit queue full.*--acker"):
            lone.send(can.Message(arbitration_id=0x310, is_extended_id=False), timeout=0.2)
    err = rig.stop()
    assert "4 frame(s) queued by departed client" in err   # given up loudly, not silently


def test_acker_acknowledges_a_lone_client(rig_factory) -> None:
    """docs/bus.md "A lone node": with `gatewaylab run --acker` a lone client's frames are acknowledged, so
    500 frames pass a 16-frame transmit queue and shutdown finds them all on the bus."""
    rig = rig_factory("--acker")
    lone = can.Bus(interface="gatewaylab", channel=rig.endpoint, tx_queue_len=16)
    for i in range(500):
        lone.send(can.Message(arbitration_id=0x400, data=i.to_bytes(2, "little"), is_extended_id=False),
                  timeout=5.0)
    lone.shutdown()
    assert lone.state is can.BusState.ACTIVE and lone.tx_errors == 0
    assert "were not transmitted" not in rig.stop()


def test_shutdown_releases_a_send_waiting_for_room_and_a_recv(rig_factory) -> None:
    """Issue 15: a send() waiting for room in a full transmit queue (a lone node: nobody acknowledges) in one
    thread and a recv() in another both end when the bus is shut down; shutdown() itself returns."""
    rig = rig_factory()
    lone = can.Bus(interface="gatewaylab", channel=rig.endpoint, tx_queue_len=1, shutdown_timeout=0.5)
    results: dict[str, object] = {}
    started = threading.Barrier(3)

    def sender() -> None:
        started.wait()
        try:
            for i in range(2):   # the second waits for room that never comes
                lone.send(can.Message(arbitration_id=0x7F0 + i, is_extended_id=False), timeout=None)
            results["send"] = "returned"
        except can.CanOperationError as exc:
            results["send"] = exc

    def receiver() -> None:
        started.wait()
        try:
            results["recv"] = lone.recv(None)
        except can.CanOperationError as exc:   # when shutdown() came first
            results["recv"] = exc

    threads = [threading.Thread(target=sender), threading.Thread(target=receiver)]
    for t in threads:
        t.start()
    started.wait()
    lone.shutdown()
    for t in threads:
        t.join(10)
        assert not t.is_alive()
    assert isinstance(results["send"], can.CanOperationError)
    assert results["recv"] is None or isinstance(results["recv"], can.CanOperationError)


def test_lone_node_with_full_queue_raises_instead_of_hanging(rig_factory) -> None:
    """docs/bus.md "A lone node": nobody acknowledges, the controller goes error-passive (CAN 2.0 fault
    confinement), and a send() with no timeout on the full queue raises instead of waiting forever."""
    rig = rig_factory()
    with can.Bus(interface="gatewaylab", channel=rig.endpoint, tx_queue_len=2, shutdown_timeout=0.5) as lone, \
         pytest.raises(can.CanOperationError, match=r"error_passive.*--acker"):
        for i in range(1000):
            lone.send(can.Message(arbitration_id=0x500 + i % 16, is_extended_id=False), timeout=None)


def test_a_notifier_whose_bus_is_shut_down_first_ends_without_an_exception(rig: Rig) -> None:
    """python-can's usual closing order, ``bus.shutdown()`` then ``notifier.stop()``: the recv() in flight in
    the Notifier's thread returns None when its timeout ends (as python-can's ``virtual`` and ``socketcan``
    buses do), so the thread sees it was stopped and never calls recv() on the closed bus (which raises
    CanOperationError: an unhandled-exception traceback in the thread before the fix)."""
    bus = can.Bus(interface="gatewaylab", channel=rig.endpoint)
    got: list[can.Message] = []
    notifier = can.Notifier(bus, [got.append], timeout=5.0)
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as sender:
        sender.send(can.Message(arbitration_id=0x321, data=b"\x01", is_extended_id=False))
        deadline = time.monotonic() + 10
        while not got and time.monotonic() < deadline:
            time.sleep(0.01)
    assert [m.arbitration_id for m in got] == [0x321]   # the Notifier was receiving
    bus.shutdown()
    notifier.stop(timeout=15.0)
    assert notifier.exception is None
    assert not [t for t in threading.enumerate() if t.name.startswith("Notifier") and bus.channel_info in t.name]
