"""CAN buses of a running rig through python-can, written the ways users write it (issue 21, "The user's path
as a suite"): a ``recv(0)`` poll loop inside a cyclic task, ``recv(timeout)``, ``for msg in bus``,
``can.Notifier`` with ``BufferedReader`` and with ``can.Logger`` files read back, ``can.Bus`` as a context
manager, CAN FD on a bus with a data bit rate, and the unhappy paths (a client that closes right after
sending, a client killed mid-stream, garbage on the bus endpoint).

One rig for the module (``gatewaylab run`` + ready file); every exchange is between two connections of the
``gatewaylab`` interface, and checks order, content and latency: the first frame after the sender connects
(< 1 s) and the steady state (p99 of send -> receive, wall clocks; userpath_kit).
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import pytest
from userpath_kit import CyclicDrain, Latencies, Received, measured, stamped, unstamp, wait_until

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"

[[bus]]
name = "can0"
bitrate = 1000000

[[bus]]
name = "canfd"
bitrate = 1000000
data_bitrate = 5000000
"""

COUNT = 200          # frames per exchange, one every PERIOD
PERIOD = 0.001       # the sender's cycle
DEADLINE = 20.0      # generous: never a timing assert, only an end to waiting
ID = 0x123
HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def rig(start_rig: Callable[..., RigProcess]) -> RigProcess:
    return start_rig(RIG)


def endpoint(rig: RigProcess, bus: str = "can0") -> str:
    return str(rig.info["buses"][bus]["endpoint"])


class Sender:
    """A client program in a thread: connects, then sends ``count`` stamped frames, one per ``period``
    (frame 0 right after the connect)."""

    def __init__(self, channel: str, count: int = COUNT, *, fd: bool = False, can_id: int = ID,
                 period: float = PERIOD) -> None:
        self.error: BaseException | None = None
        self._args = (channel, count, fd, can_id, period)
        self._thread = threading.Thread(target=self._run, name="sender")
        self._thread.start()

    def _run(self) -> None:
        channel, count, fd, can_id, period = self._args
        size = 64 if fd else 8
        try:
            with can.Bus(interface="gatewaylab", channel=channel) as bus:
                for seq in range(count):
                    data = stamped(seq, size)
                    bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False, is_fd=fd,
                                         bitrate_switch=fd))
                    time.sleep(period)
        except BaseException as exc:   # reported by join()
            self.error = exc

    def join(self) -> None:
        self._thread.join(DEADLINE)
        assert not self._thread.is_alive(), "sender hangs"
        if self.error is not None:
            raise self.error


def check_exchange(label: str, got: Received, count: int = COUNT, *, can_id: int = ID,
                   **bounds: float) -> Latencies:
    """Every frame arrived once, in order, intact; the latency of the first and the steady state
    (``bounds``: Latencies.check's, when not the default ones)."""
    seqs = [unstamp(msg.data)[0] for msg, _ in got]
    assert seqs == list(range(count))
    assert all(msg.arbitration_id == can_id and msg.is_rx for msg, _ in got)
    lat = Latencies(label)
    for msg, received in got:
        seq, sent = unstamp(msg.data)
        if seq == 0:
            lat.first = received - sent
        else:
            lat.add(received - sent)
    lat.check(**bounds)
    return lat


def exchange(channel: str, receive: Callable[[can.BusABC, int], Received], count: int = COUNT,
             fd: bool = False) -> Received:
    """The receiver connects (a context manager), a sender connects and sends; ``receive`` is the user's
    receiving code."""
    with can.Bus(interface="gatewaylab", channel=channel) as rx:
        sender = Sender(channel, count, fd=fd)
        try:
            got = receive(rx, count)
        finally:
            sender.join()
    return got


# -- the receiving code, as users write it ---------------------------------------------------------------
def by_poll_loop(bus: can.BusABC, count: int) -> Received:
    """A cyclic task (a thread waking every 2 ms) drains with ``while (msg := bus.recv(0)) is not None``."""
    task = CyclicDrain(bus)
    try:
        wait_until(lambda: len(task.received) >= count, DEADLINE, f"{count} frames by recv(0)")
    finally:
        task.stop()
    return task.received


def by_recv_timeout(bus: can.BusABC, count: int) -> Received:
    got: Received = []
    while len(got) < count:
        msg = bus.recv(2.0)
        assert msg is not None, f"recv(2.0) timed out after {len(got)} frames"
        got.append((msg, time.time()))
    return got


def by_iteration(bus: can.BusABC, count: int) -> Received:
    got: Received = []
    watchdog = threading.Timer(DEADLINE, bus.shutdown)   # ends the loop (recv raises) if frames stop coming
    watchdog.start()
    try:
        for msg in bus:
            got.append((msg, time.time()))
            if len(got) == count:
                break
    finally:
        watchdog.cancel()
    return got


def by_buffered_reader(bus: can.BusABC, count: int, *others: can.Listener) -> Received:
    """A Notifier feeding a BufferedReader (and ``others``, e.g. a can.Logger); stopping the notifier
    stops its listeners (a logger closes its file)."""
    reader = can.BufferedReader()
    notifier = can.Notifier(bus, [reader, *others])
    got: Received = []
    try:
        while len(got) < count:
            msg = reader.get_message(2.0)
            assert msg is not None, f"BufferedReader gave nothing after {len(got)} frames"
            got.append((msg, time.time()))
    finally:
        notifier.stop()
    return got


# -- tests --------------------------------------------------------------------------------------------------
@measured
def test_recv_zero_poll_loop_in_a_cyclic_task(rig: RigProcess) -> None:
    """python-can BusABC.recv: timeout 0 returns what has arrived without waiting. A cyclic task's drain
    (``while (msg := bus.recv(0)) is not None``) gets every frame, in order, promptly (issue 21 defect 1:
    it got nothing, forever)."""
    check_exchange("recv(0) poll loop, cyclic task 2 ms", exchange(endpoint(rig), by_poll_loop))


@measured
def test_recv_with_timeout(rig: RigProcess) -> None:
    """python-can BusABC.recv(timeout): blocks until a frame arrives or the timeout passes."""
    check_exchange("recv(2.0)", exchange(endpoint(rig), by_recv_timeout))


@measured
def test_for_msg_in_bus(rig: RigProcess) -> None:
    """python-can BusABC.__iter__: ``for msg in bus`` yields every received frame."""
    check_exchange("for msg in bus", exchange(endpoint(rig), by_iteration))


@measured
def test_notifier_with_buffered_reader(rig: RigProcess) -> None:
    """python-can Notifier + BufferedReader: the notifier thread reads, the program takes the frames with
    ``get_message(timeout)``."""
    check_exchange("Notifier + BufferedReader", exchange(endpoint(rig), by_buffered_reader))


@pytest.mark.parametrize("suffix", [".log", ".asc", ".csv"])
@measured
def test_notifier_with_logger_file_read_back(rig: RigProcess, tmp_path: Path, suffix: str) -> None:
    """python-can Notifier + can.Logger (the writer chosen by the file's suffix: candump .log, Vector .asc,
    .csv) beside a BufferedReader, as a logging program does; the file read back with can.LogReader holds
    every frame, in order, with its data."""
    path = tmp_path / f"trace{suffix}"
    got = exchange(endpoint(rig), lambda bus, count: by_buffered_reader(bus, count, can.Logger(str(path))))
    check_exchange(f"Notifier + Logger({suffix})", got)
    logged = [m for m in can.LogReader(str(path)) if not m.is_error_frame]
    assert [(m.arbitration_id, bytes(m.data)) for m in logged] == [(ID, bytes(m.data)) for m, _ in got]


@measured
def test_can_fd_frames_with_bit_rate_switch(rig: RigProcess) -> None:
    """A bus with data_bitrate carries CAN FD (ISO 11898-1:2015): 64-byte frames with BRS arrive whole, as
    FD frames with BRS set, in order, through a poll loop and through recv(timeout)."""
    channel = endpoint(rig, "canfd")
    for label, receive in (("FD recv(0) poll loop", by_poll_loop), ("FD recv(2.0)", by_recv_timeout)):
        got = exchange(channel, receive, fd=True)
        assert all(msg.is_fd and msg.bitrate_switch and len(msg.data) == 64 for msg, _ in got)
        check_exchange(label, got)


CHILD_SENDER = textwrap.dedent("""
    import sys, time
    import can
    from userpath_kit import stamped
    channel, count, period = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    with can.Bus(interface="gatewaylab", channel=channel) as bus:
        for seq in range(count):
            data = stamped(seq)
            bus.send(can.Message(arbitration_id=0x123, data=data, is_extended_id=False), timeout=10)
            if period:
                time.sleep(period)
""")


def child_sender(channel: str, count: int, period: float) -> subprocess.Popen[bytes]:
    """A user's program in its own process sending ``count`` stamped frames (0 = for ever)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(HERE), os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, "-c", CHILD_SENDER, channel, str(count if count else 60000),
                             str(period)], env=env)


@measured
def test_client_closing_right_after_sending_loses_nothing(rig: RigProcess) -> None:
    """A program that sends a burst and exits at once (``with can.Bus(...)``: shutdown as it leaves) gets
    every frame onto the bus: the receiver gets all of them, in order (docs/bus-wire.md, SocketCAN's
    promise). The burst queues behind the bus (1 Mbit/s), so the median's bound is the queue's."""
    count = 500
    with can.Bus(interface="gatewaylab", channel=endpoint(rig)) as rx:
        child = child_sender(endpoint(rig), count, 0.0)
        try:
            got = by_recv_timeout(rx, count)
            assert child.wait(DEADLINE) == 0
        finally:
            child.kill()
            child.wait()
    # 128 frames in flight (DEFAULT_TX_QUEUE_LEN) x ~0.13 ms each on the bus: tens of ms behind in a burst
    check_exchange("burst then exit (child process)", got, count, median_bound=0.1)


@measured
def test_client_killed_mid_stream_rig_and_other_clients_carry_on(rig: RigProcess) -> None:
    """SIGKILL of a sending program (its socket vanishes mid-stream): what it sent arrives as a gap-free
    prefix, the rig stays up, the listener that was connected all along and a new sender carry on with
    their usual latency."""
    channel = endpoint(rig)
    with can.Bus(interface="gatewaylab", channel=channel) as rx:
        task = CyclicDrain(rx)
        child = child_sender(channel, 0, PERIOD)
        try:
            wait_until(lambda: len(task.received) >= 50, DEADLINE, "50 frames of the child")
        finally:
            os.kill(child.pid, signal.SIGKILL)
            child.wait()
        killed_seqs = [unstamp(m.data)[0] for m, _ in task.received]
        assert killed_seqs == list(range(len(killed_seqs)))
        assert rig.proc.poll() is None, "the rig died with its client"
        # the rig and the listener carry on: a new program sends another stream (another id)
        before = len(task.received)
        sender = Sender(channel, can_id=0x321)
        sender.join()
        wait_until(lambda: sum(m.arbitration_id == 0x321 for m, _ in task.received) >= COUNT, DEADLINE,
                   "the new sender's frames")
        task.stop()
    late_of_killed = [unstamp(m.data)[0] for m, _ in task.received[before:] if m.arbitration_id == ID]
    all_killed = killed_seqs + late_of_killed   # its queue in the rig may still drain after the kill
    assert all_killed == list(range(len(all_killed)))
    after = [(m, t) for m, t in task.received if m.arbitration_id == 0x321]
    check_exchange("after a SIGKILLed client: new sender -> old listener", after, can_id=0x321)


def garbage_connection(channel: str, payload: bytes) -> None:
    """Connect to the bus endpoint like a client, write ``payload``, close."""
    assert channel.startswith("unix:"), channel
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(5)
        sock.connect(channel[len("unix:"):])
        try:
            sock.sendall(payload)
        except OSError:
            pass   # the rig may hang up on the first bad record


@measured
def test_garbage_on_the_bus_endpoint_leaves_the_rig_and_other_clients_alone(rig: RigProcess) -> None:
    """docs/bus-wire.md: a client that sends malformed records loses its own connection only. Random bytes,
    a valid HELLO then random bytes, and half a record, each on its own connection while two clients
    exchange frames: the exchange is whole and on time, the rig stays up (one log line per bad connection,
    no traceback) and accepts new clients."""
    from gatewaylab.bus.wire import encode_hello

    channel = endpoint(rig)
    rnd = random.Random(21)
    payloads = [rnd.randbytes(4096), encode_hello("garbage") + rnd.randbytes(4096), encode_hello("half")[:5]]
    malformed_before = rig.log_text().count("malformed data")

    def receive(bus: can.BusABC, count: int) -> Received:
        task = CyclicDrain(bus)
        try:
            for payload in payloads:
                garbage_connection(channel, payload)
            wait_until(lambda: sum(m.arbitration_id == ID for m, _ in task.received) >= count, DEADLINE,
                       f"{count} frames beside the garbage")
        finally:
            task.stop()
        return [(m, t) for m, t in task.received if m.arbitration_id == ID]

    check_exchange("beside garbage connections", exchange(channel, receive))
    assert rig.proc.poll() is None, "the rig died of garbage"
    log = rig.log_text()
    assert "Traceback" not in log
    assert 1 <= log.count("malformed data") - malformed_before <= len(payloads)   # a line each, no flood
    check_exchange("a new pair after the garbage", exchange(channel, by_recv_timeout))
