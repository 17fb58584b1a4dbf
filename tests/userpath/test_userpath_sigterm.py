"""SIGTERM as a user sends it (issue 21, defect 5): `gatewaylab run` must end within 1 s in every state.

docs/rig.md 'Running a rig': "SIGINT/SIGTERM shut it down cleanly and remove the endpoints, the
temporary folder and the ready file, and the process exits within one second in every state". The bound
is asserted as promised, without a margin: the stop path waits on no timeout, and these tests measure
20-300 ms on a loaded 2-CPU machine (the old code: 0.7 s idle, 1-3 s with SOEM traffic, killed while
starting). Each test starts the rig exactly as a user does (``gatewaylab run RIG.toml --ready-file``,
through :class:`RigProcess`) with CAN buses, drives, a maxon IDX (pty + TCP), an esd CAN-EtherCAT (with
its web server), an ECAN-Lite and a Modbus gateway, the EtherCAT segment on a veth pair, `--web` and
`--trace`, puts it in one state (idle, mid-bring-up, SOEM scanning, SOEM at 1 kHz, flooded by python-can
clients and SOEM back to back with clients connected), sends SIGTERM and measures the time until the
process has exited; then checks that the temporary folder, its sockets and the ready file are gone.

Run as its own driver too (the subprocesses of the tests): ``--flood ENDPOINT N`` (N python-can
clients sending as fast as the rig takes frames) and ``--soem IFACE PERIOD`` (pysoem to OP, then process
data every PERIOD seconds, 0 = back to back).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

#: docs/rig.md: the rig exits within one second of SIGTERM.
STOP_BOUND_S = 1.0


# ------------------------------------------------------------------------------------- drivers
#: frames each flooding client has sent when the driver says ``flooding`` (the rig's queues are full)
FLOOD_STARTED = 500


def flood(endpoint: str, clients: int) -> None:
    """``clients`` python-can clients on ``endpoint``, each sending back to back until killed; prints
    ``flooding`` once each has sent FLOOD_STARTED frames or found its transmit queue full (the clients'
    identifiers differ, so at full bus load the lowest wins every arbitration and starves the others)."""
    import can

    buses = [can.Bus(interface="gatewaylab", channel=endpoint) for _ in range(clients)]
    started = threading.Semaphore(0)

    def send(k: int, bus: can.BusABC) -> None:
        i = 0
        released = False
        while True:
            i += 1
            try:
                bus.send(can.Message(arbitration_id=0x100 + k, data=i.to_bytes(8, "little"), is_extended_id=False),
                         timeout=1.0)
                full = False
            except can.CanError:      # the transmit queue stayed full for a second: keep pushing
                i -= 1
                full = True           # a lower-priority client loses every arbitration to a flood: its queue is full
            if not released and (i >= FLOOD_STARTED or full):
                released = True
                started.release()

    for k, bus in enumerate(buses):
        threading.Thread(target=send, args=(k, bus), daemon=True).start()
    for _ in buses:
        started.acquire()
    print("flooding", flush=True)
    threading.Event().wait()


def soem(iface: str, period: float) -> None:
    """pysoem: bring the line up (prints ``scanning`` as it starts, ``exchanging N`` after 200 process data
    cycles), then exchange process data every ``period`` seconds (0: back to back) until killed."""
    import pysoem

    master = pysoem.Master()
    master.sdo_read_timeout = master.sdo_write_timeout = 3_000_000
    master.open(iface)
    print("scanning", flush=True)
    count = 0
    for _ in range(5):     # a veth link just brought up may lose the first frames
        count = master.config_init()
        if count > 0:
            break
    for attempt in range(3):    # a loaded machine may answer a mapping read later than SOEM waits
        try:
            master.config_map()
            break
        except pysoem.ConfigMapError:
            if attempt == 2:
                raise
    master.state_check(pysoem.SAFEOP_STATE, 50_000)
    master.state = pysoem.OP_STATE
    master.write_state()
    t_next = time.perf_counter()
    announced = False
    cycles = 0
    while True:
        master.send_processdata()
        master.receive_processdata(20_000)
        cycles += 1
        if not announced and cycles >= 200:
            print(f"exchanging {count}", flush=True)
            announced = True
        if cycles % 100 == 0 and master.state_check(pysoem.OP_STATE, 1000) != pysoem.OP_STATE:
            master.state = pysoem.OP_STATE
            master.write_state()
        t_next += period
        slack = t_next - time.perf_counter()
        if slack > 0:
            time.sleep(slack)
        else:
            t_next = time.perf_counter()


if __name__ == "__main__":
    if sys.argv[1] == "--flood":
        flood(sys.argv[2], int(sys.argv[3]))
    elif sys.argv[1] == "--soem":
        soem(sys.argv[2], float(sys.argv[3]))
    raise SystemExit(0)


# --------------------------------------------------------------------------------------- tests
import pytest  # noqa: E402
from wire_kit import net_capable, veth_namespace  # noqa: E402

from gatewaylab.rig.process import RigProcess  # noqa: E402

HERE = Path(__file__).resolve()


def rig_text(interface: str) -> str:
    """Two buses, three drives, an IDX on pty + TCP, an esd gateway with its web page and an ECAN-Lite on
    the EtherCAT segment on ``interface``."""
    return f"""
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 500000
[[bus]]
name = "can1"
bitrate = 1000000
[[device]]
kind = "maxon_idx"
name = "idx1"
bus = "can1"
node_id = 1
usb = {{ pty = true, tcp_port = 0 }}
[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"
web_port = 0
[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can1"]
[[device]]
kind = "modbus_gateway"
name = "mb1"
bus = "can0"
node_id = 10
nodes = [2]
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "a2"
[[drive]]
bus = "can1"
node_id = 3
serial = 0x1003
name = "a3"
[[drive]]
bus = "can1"
node_id = 4
serial = 0x1004
name = "a4"
[ethercat]
interface = "{interface}"
"""


#: (namespace, the emulator's end, the master's end inside the namespace): tests/wire_kit.py
Line = tuple[str, str, str]


@pytest.fixture(scope="module")
def sigterm_line() -> Iterator[Line]:
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-st-", "glst") as line:
        yield line


def _driver(*args: str, namespace: str | None = None) -> subprocess.Popen[str]:
    cmd = [sys.executable, str(HERE), *args]
    if namespace is not None:
        cmd = ["ip", "netns", "exec", namespace, *cmd]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def _wait_line(proc: subprocess.Popen[str], prefix: str, timeout: float = 60.0) -> str:
    """The first stdout line of ``proc`` starting with ``prefix`` (the driver's progress)."""
    assert proc.stdout is not None
    out: IO[str] = proc.stdout
    result: list[str] = []

    def read() -> None:
        for line in out:
            if line.startswith(prefix):
                result.append(line.strip())
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout)
    if not result:
        proc.kill()
        _, err = proc.communicate(timeout=10)
        raise AssertionError(f"driver {proc.args!r} never printed {prefix!r}: {err[-2000:]}")
    return result[0]


def _end(*procs: subprocess.Popen[str]) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)


def _sigterm_seconds(proc: subprocess.Popen[Any]) -> float:
    """SIGTERM, then the seconds until the process has exited (waited for up to 10 s)."""
    t0 = time.monotonic()
    proc.terminate()
    proc.wait(10)
    return time.monotonic() - t0


def _left_behind(tmp_path: Path) -> list[str]:
    """What a clean stop must have removed: the ready file, the rig's state folder (its bus and control
    sockets, stored parameters) in the child's TMPDIR."""
    return sorted(str(p) for p in (*tmp_path.glob("ready-*.json"), *(tmp_path / "tmp").iterdir()))


def _rig_args(tmp_path: Path, line: Line) -> list[str]:
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(rig_text(line[1]))
    return [str(rig_file), "--web", "--trace", f"can0={tmp_path / 'can0.log'}",
            "--trace", f"can1={tmp_path / 'can1.blf'}"]


@pytest.fixture
def child_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The rig child's TMPDIR (where its ``gatewaylab-*`` state folder goes), to see it removed; seen
    as ``tmp_path / "tmp"``. A short folder of its own: the control socket's path below it must fit
    AF_UNIX's 107 bytes, which pytest-xdist's ``popen-gwN/test_name0`` prefix would overrun."""
    short = Path(tempfile.mkdtemp(prefix="s"))
    (tmp_path / "tmp").symlink_to(short)
    monkeypatch.setenv("TMPDIR", str(short))
    yield tmp_path
    shutil.rmtree(short, ignore_errors=True)


def _start(tmp_path: Path, line: Line) -> RigProcess:
    rig_file, *extra = _rig_args(tmp_path, line)
    return RigProcess(rig_file, *extra, workdir=tmp_path, timeout=90)


def _check_stop(rig: RigProcess, seconds: float, tmp_path: Path, state: str) -> None:
    print(f"SIGTERM {state}: exited after {seconds * 1000:.0f} ms")
    assert rig.proc.returncode == 0, rig.log_text()[-2000:]
    assert _left_behind(tmp_path) == []
    assert "Traceback" not in rig.log_text()
    assert seconds < STOP_BOUND_S, f"{state}: {seconds:.2f} s"


def test_sigterm_idle(child_tmp: Path, sigterm_line: Line) -> None:
    """docs/rig.md 'Running a rig': an idle rig (no master, no client) exits within a second of SIGTERM
    with exit 0; ready file, state folder and sockets are gone."""
    with _start(child_tmp, sigterm_line) as rig:
        seconds = _sigterm_seconds(rig.proc)
    _check_stop(rig, seconds, child_tmp, "idle")


def test_sigterm_while_the_rig_starts(child_tmp: Path, sigterm_line: Line) -> None:
    """docs/rig.md 'Running a rig': SIGTERM while `gatewaylab run` builds and starts its devices (its state
    folder exists, the ready file does not yet) ends it within a second and leaves nothing behind."""
    ready = child_tmp / "ready-bringup.json"
    proc = subprocess.Popen([sys.executable, "-m", "gatewaylab", "run", *_rig_args(child_tmp, sigterm_line),
                             "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        # the state folder, not any entry: Python's own probe of TMPDIR (a file it makes and removes
        # at once) comes first and is not the rig's to clean up
        while not any((child_tmp / "tmp").glob("gatewaylab-*")) and proc.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.001)
        assert not ready.exists(), "the rig started before the signal: nothing mid-bring-up was tested"
        seconds = _sigterm_seconds(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        _, err = proc.communicate(timeout=10)
    print(f"SIGTERM mid-bring-up: exited after {seconds * 1000:.0f} ms")
    assert proc.returncode == 0, err.decode(errors="replace")[-2000:]
    assert _left_behind(child_tmp) == []
    assert seconds < STOP_BOUND_S


def test_sigterm_while_soem_brings_the_line_up(child_tmp: Path, sigterm_line: Line) -> None:
    """docs/rig.md 'Running a rig': SIGTERM while SOEM scans the line and configures its slaves (mailbox
    traffic on the wire thread) ends the rig within a second."""
    with _start(child_tmp, sigterm_line) as rig:
        master = _driver("--soem", sigterm_line[2], "0.001", namespace=sigterm_line[0])
        try:
            _wait_line(master, "scanning", timeout=60)      # config_init: hundreds of frames follow
            seconds = _sigterm_seconds(rig.proc)
        finally:
            _end(master)
    _check_stop(rig, seconds, child_tmp, "while SOEM brings the line up")


def test_sigterm_while_soem_exchanges_at_1khz(child_tmp: Path, sigterm_line: Line) -> None:
    """docs/rig.md 'Running a rig': SOEM in OP exchanging process data at 1 kHz (a frame on the wire thread
    every millisecond, also while the rig stops): exit within a second, exit 0."""
    with _start(child_tmp, sigterm_line) as rig:
        master = _driver("--soem", sigterm_line[2], "0.001", namespace=sigterm_line[0])
        try:
            _wait_line(master, "exchanging", timeout=90)
            seconds = _sigterm_seconds(rig.proc)
        finally:
            _end(master)
    _check_stop(rig, seconds, child_tmp, "while SOEM exchanges at 1 kHz")


def test_sigterm_under_load(child_tmp: Path, sigterm_line: Line) -> None:
    """docs/rig.md 'Running a rig': SOEM exchanging process data back to back, three python-can clients flooding
    each bus, a client on the IDX's pty and one on its TCP port, one on the esd web page and one on the
    rig's live page (an endless event stream): the rig exits within a second of SIGTERM, exit 0."""
    import serial

    drivers: list[subprocess.Popen[str]] = []
    with _start(child_tmp, sigterm_line) as rig:
        try:
            master = _driver("--soem", sigterm_line[2], "0", namespace=sigterm_line[0])
            drivers.append(master)
            _wait_line(master, "exchanging", timeout=90)
            for bus in ("can0", "can1"):
                drivers.append(_driver("--flood", rig.endpoint(bus), "3"))
                _wait_line(drivers[-1], "flooding")
            usb = rig.info["usb"]["idx1"]
            pty = serial.Serial(usb["pty"], timeout=0)
            clients = [socket.create_connection(_host_port(usb["tcp"]), timeout=5)]
            for url, request in ((rig.info["web"]["esd1"], b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"),
                                 (rig.info["web"]["monitor"], b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")):
                clients.append(socket.create_connection(_host_port(url), timeout=30))
                clients[-1].sendall(request)
                assert clients[-1].recv(12).startswith(b"HTTP/1."), url     # served, connection kept open
            seconds = _sigterm_seconds(rig.proc)
            pty.close()
            for client in clients:
                client.close()
        finally:
            _end(*drivers)
    _check_stop(rig, seconds, child_tmp, "under load")


def _host_port(endpoint: str) -> tuple[str, int]:
    """("127.0.0.1", port) of ``tcp:127.0.0.1:PORT`` or ``http://127.0.0.1:PORT/...``."""
    hostport = endpoint.removeprefix("tcp:").removeprefix("http://").split("/", 1)[0]
    host, port = hostport.rsplit(":", 1)
    return host, int(port)
