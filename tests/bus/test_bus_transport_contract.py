"""The python-can contract of the `gatewaylab` interface (issue 15, "The python-can and canopen contracts"):
shutdown while another thread reads, timestamps, channel, own echoes, CAN FD checks, acceptance filters."""

import threading
import time
from collections.abc import Iterator

import can
import pytest
from transport_testkit import Rig, drain, one_rig


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    """One rig for the module: each test opens its own clients and leaves nothing queued."""
    yield from one_rig(tmp_path_factory.mktemp("rig"))


def test_shutdown_interrupts_a_recv_in_another_thread_with_none(rig: Rig) -> None:
    """Issue 15: "A recv() interrupted by the bus's own shutdown() returns None; any call after shutdown()
    raises can.CanOperationError" (before: CanOperationError from a closed socket, then ValueError)."""
    bus = can.Bus(interface="gatewaylab", channel=rig.endpoint)
    results: list[object] = []
    entered = threading.Event()

    def reader() -> None:
        entered.set()
        try:
            results.append(bus.recv(None))
        except Exception as exc:  # recorded, asserted below
            results.append(exc)

    thread = threading.Thread(target=reader)
    thread.start()
    assert entered.wait(10)
    bus.shutdown()
    thread.join(10)
    assert not thread.is_alive() and results == [None]
    with pytest.raises(can.CanOperationError):
        bus.recv(0)
    with pytest.raises(can.CanOperationError):
        bus.send(can.Message(arbitration_id=1, is_extended_id=False))
    bus.shutdown()   # a second shutdown is harmless


def test_notifier_stopped_without_waiting_then_shutdown_reports_no_error(rig: Rig) -> None:
    """Issue 15: a can.Notifier (what every canopen Network runs) told to stop without waiting for its
    reader, then the bus shut down while the reader is in recv(): the reader ends without an exception."""
    bus = can.Bus(interface="gatewaylab", channel=rig.endpoint)
    errors: list[Exception] = []

    class Spy(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            pass

        def on_error(self, exc: Exception) -> None:
            errors.append(exc)

    notifier = can.Notifier(bus, [Spy()], timeout=30.0)
    notifier.stop(timeout=0.0)      # the reader thread is still in recv(30.0)
    bus.shutdown()
    for reader in notifier._readers:
        assert isinstance(reader, threading.Thread)
        reader.join(10.0)
        assert not reader.is_alive()
    assert errors == [] and notifier.exception is None


def test_timestamp_is_unix_time_channel_is_the_callers_echo_is_tx(rig: Rig) -> None:
    """python-can Message docs: timestamp in seconds since the epoch; channel as given to can.Bus; an own
    echo (receive_own_messages=True) has is_rx=False, a received frame is_rx=True (issue 15)."""
    before = time.time()
    with can.Bus(interface="gatewaylab", channel=rig.endpoint, receive_own_messages=True) as a, \
         can.Bus(interface="gatewaylab", channel=rig.endpoint) as b:
        sent = can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False)
        a.send(sent)
        echo = a.recv(10)
        got = b.recv(10)
        after = time.time()
    assert echo is not None and got is not None
    assert echo.is_rx is False and got.is_rx is True
    assert echo.channel == got.channel == rig.endpoint
    assert before - 1.0 <= got.timestamp <= after + 1.0     # Unix time, not time since the rig started
    assert echo.timestamp == got.timestamp                  # the same bus instant: the end of the frame
    sent.channel = rig.endpoint
    assert sent.equals(got, timestamp_delta=None)


def test_fd_frame_from_a_classic_client_is_refused_and_the_connection_stays(rig: Rig) -> None:
    """Issue 15: a client opened with fd=False that sends an FD frame gets can.CanOperationError from send();
    before, the rig dropped the whole connection."""
    with can.Bus(interface="gatewaylab", channel=rig.endpoint, fd=False) as classic, \
         can.Bus(interface="gatewaylab", channel=rig.endpoint) as other:
        with pytest.raises(can.CanOperationError, match="fd=False"):
            classic.send(can.Message(arbitration_id=0x10, data=bytes(12), is_fd=True))
        classic.send(can.Message(arbitration_id=0x11, data=b"ok", is_extended_id=False))
        msg = other.recv(10)
    assert msg is not None and msg.arbitration_id == 0x11


def test_fd_payload_of_invalid_length_is_padded_like_socketcan(rig: Rig) -> None:
    """ISO 11898-1:2015 FD lengths 0-8,12,16,20,24,32,48,64; SocketCAN pads a 10-byte payload to 12 with
    zeros instead of refusing it (issue 15)."""
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as a, \
         can.Bus(interface="gatewaylab", channel=rig.endpoint) as b:
        a.send(can.Message(arbitration_id=0x20, data=bytes(range(1, 11)), is_fd=True, is_extended_id=False))
        msg = b.recv(10)
    assert msg is not None and msg.is_fd
    assert bytes(msg.data) == bytes(range(1, 11)) + b"\0\0" and msg.dlc == 12


def test_filters_are_applied_by_the_rig(rig: Rig) -> None:
    """python-can set_filters()/can_filters: `id & mask == can_id & mask`, `extended` if given. Issue 15: the
    rig applies them, filtered frames never cross the socket, and the bus reports them as already filtered."""
    filters = [{"can_id": 0x100, "can_mask": 0x7F0, "extended": False}]
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as sender, \
         can.Bus(interface="gatewaylab", channel=rig.endpoint, can_filters=filters) as filtered:
        for i in range(40):
            sender.send(can.Message(arbitration_id=0x100 + (i % 32), is_extended_id=bool(i % 3 == 0), data=[i]))
        sender.send(can.Message(arbitration_id=0x10F, is_extended_id=False, data=b"end"))
        crossed = []
        while True:   # what crossed the socket, as _recv_internal hands it to BusABC.recv
            msg, already_filtered = filtered._recv_internal(10.0)
            assert msg is not None and already_filtered
            crossed.append(msg)
            if bytes(msg.data) == b"end":
                break
        # set_filters() later takes effect the same way
        filtered.set_filters([{"can_id": 0x7FF, "can_mask": 0x7FF}])
        sender.send(can.Message(arbitration_id=0x101, is_extended_id=False))
        sender.send(can.Message(arbitration_id=0x7FF, is_extended_id=False))
        last = filtered.recv(10.0)
    expected = [i for i in range(40) if i % 3 and (0x100 + i % 32) & 0x7F0 == 0x100]
    assert [m.data[0] for m in crossed[:-1]] == expected
    assert all(not m.is_extended_id and m.arbitration_id & 0x7F0 == 0x100 for m in crossed)
    assert last is not None and last.arbitration_id == 0x7FF


def test_many_filters_fall_back_to_filtering_in_the_client(rig: Rig) -> None:
    """More filters than one FILTER record holds (docs/bus-wire.md): the client filters itself, BusABC.recv
    still returns only matching frames."""
    filters = [{"can_id": 0x200 + i, "can_mask": 0x7FF} for i in range(60)]
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as sender, \
         can.Bus(interface="gatewaylab", channel=rig.endpoint, can_filters=filters) as filtered:
        for can_id in (0x100, 0x201, 0x300, 0x23B):
            sender.send(can.Message(arbitration_id=can_id, is_extended_id=False))
        got = drain(filtered, 2)
    assert [m.arbitration_id for m in got] == [0x201, 0x23B]


@pytest.mark.parametrize("timeout", [0, 1e-6])
def test_recv_zero_poll_loop_in_a_cyclic_task_drains_every_frame(rig: Rig, timeout: float) -> None:
    """python-can BusABC.recv: "timeout -- seconds to wait for a message or None to wait indefinitely";
    0 means "do not wait": return what has already arrived. Issue 21 defect 1: `recv(0)` gave up before
    reading the socket, so the poll loop of a cyclic task (`while (msg := bus.recv(0)) is not None`) got
    nothing, forever; python-can's `virtual` returns every frame. The same for a timeout that is over
    before the socket is read (1 us)."""
    count = 50
    with can.Bus(interface="gatewaylab", channel=rig.endpoint) as a, \
         can.Bus(interface="gatewaylab", channel=rig.endpoint) as b:
        for i in range(count):
            a.send(can.Message(arbitration_id=0x300, data=i.to_bytes(2, "little"), is_extended_id=False))
        got: list[can.Message] = []
        deadline = time.monotonic() + 20.0          # generous: no timing is asserted
        while len(got) < count and time.monotonic() < deadline:
            while (msg := b.recv(timeout)) is not None:   # the cyclic task's drain
                got.append(msg)
            time.sleep(0.002)                       # the task's period
    assert [int.from_bytes(m.data, "little") for m in got] == list(range(count))
