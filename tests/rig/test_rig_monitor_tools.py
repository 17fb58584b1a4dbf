"""The everyday CAN tools against a running rig, as a user runs them (issue 25): `gatewaylab dump`
(candump), `gatewaylab send` (cansend), `gatewaylab monitor --plain` with the rig's controller
events, `--viewer`, and `--replay` of the traces `run --trace` writes."""

from __future__ import annotations

import json
import os
import queue
import re
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from gatewaylab.rig.process import RigProcess

WAIT = 60.0     # generous: the machine is shared, a CLI needs seconds to start under load
GL = [sys.executable, "-m", "gatewaylab"]

LONE_RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
"""


def gl(*args: str, timeout: float = WAIT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GL, *args], capture_output=True, text=True, timeout=timeout)


class Lines:
    """The output lines of a running CLI, read by a thread, waited for with a predicate."""

    def __init__(self, proc: subprocess.Popen[str], stream: str = "stdout") -> None:
        self.proc = proc
        self.lines: list[str] = []
        self._q: queue.Queue[str] = queue.Queue()
        pipe = getattr(proc, stream)
        threading.Thread(target=lambda: [self._q.put(ln.rstrip("\n")) for ln in pipe], daemon=True).start()

    def until(self, want: Callable[[str], bool], timeout: float = WAIT,
              poke: Callable[[], object] | None = None) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                ln = self._q.get(timeout=0.5)
            except queue.Empty:
                if poke is not None:
                    poke()
                continue
            self.lines.append(ln)
            if want(ln):
                return ln
        raise AssertionError(f"not seen in {timeout} s; got {self.lines[-20:]}")


@contextmanager
def cli(*args: str, stderr_lines: bool = False) -> Iterator[Lines]:
    proc = subprocess.Popen([*GL, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        yield Lines(proc, "stderr" if stderr_lines else "stdout")
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    tmp = tmp_path_factory.mktemp("tools")
    with RigProcess(None, "--trace", f"can0={tmp / 'trace.pcapng'}", workdir=tmp, timeout=WAIT) as r:
        yield r


def test_send_then_dump_prints_candump_lines_and_error_frames(rig: RigProcess) -> None:
    """can-utils candump -t z -e with a filter 123:7FF,#FFFFFFFF: only 0x123 frames and every error frame,
    one line each as candump prints them; a corrupted frame is an ERRORFRAME line with the kernel's
    error classes below it (protocol violation at the CRC sequence), then its retransmission."""
    ready = str(rig.ready_file)
    with cli("dump", ready, "-t", "z", "-e", "-f", "123:7FF,#FFFFFFFF", "--duration", "120") as dump:
        first = dump.until(lambda ln: "123   [1]  00" in ln, poke=lambda: gl("send", ready, "123#00"))
        assert re.fullmatch(r" \(\d{3}\.\d{6}\)  can0  123   \[1\]  00", first)
        assert gl("send", ready, "124#00").returncode == 0           # filtered out
        assert gl("fault", ready, "corrupt", "can0", "0x123").returncode == 0
        assert gl("send", ready, "123#DEADBEEF").returncode == 0
        dump.until(lambda ln: "123   [4]  DE AD BE EF" in ln)
        assert gl("send", ready, "123##1" + "11" * 9).returncode == 0     # CAN FD, padded to 12 as cansend
        dump.until(lambda ln: "123  [12]  " + " ".join(["11"] * 9 + ["00"] * 3) in ln)
    text = "\n".join(dump.lines)
    assert "124" not in text
    assert re.search(r"can0  20000288   \[8\]  00 00 00 08 00 00 00 0\d   ERRORFRAME\n"
                     r"\tprotocol-violation\{\{\}\{crc-sequence\}\}\n\tbus-error\n", text), text


def test_monitor_shows_controller_events_and_raw_frames(rig: RigProcess) -> None:
    """docs/faults.md: bus-off of a drive (auto-recovery after 128 x 11 bits), an unplugged cable and a
    frame that is not CANopen (0x100 with 4 bytes) appear in the decoded log."""
    ready = str(rig.ready_file)
    with cli("monitor", ready, "--plain", "--duration", "120") as mon:
        mon.until(lambda ln: "DE AD BE EF" in ln, poke=lambda: gl("send", ready, "100#DEADBEEF"))
        assert gl("fault", ready, "bus-off", "axis2").returncode == 0
        mon.until(lambda ln: "CAN axis2:" in ln and "bus-off" in ln)
        assert gl("fault", ready, "can-unplug", "axis3").returncode == 0
        mon.until(lambda ln: "CAN axis3: unplugged, left the bus" in ln)
        assert gl("fault", ready, "can-replug", "axis3").returncode == 0
        mon.until(lambda ln: "CAN axis3: plugged in again" in ln)
    raw = next(ln for ln in mon.lines if "DE AD BE EF" in ln)
    assert raw.split("  ", 1)[1].strip() == "100   [4]  DE AD BE EF" and "TIME" not in raw


def test_send_usage_and_not_acknowledged_exit_codes(tmp_path: Path) -> None:
    """docs/cli.md exit codes: a bad frame or a missing ready file is a usage error (2), a frame nobody
    acknowledges (a lone client) is 1 with what to do, a frame that reached the bus 0."""
    bad = gl("send", "nosuch.json", "123#00")
    assert bad.returncode == 2 and "no such ready file" in bad.stderr
    rig_file = tmp_path / "lone.toml"
    rig_file.write_text(LONE_RIG)
    with RigProcess(rig_file, workdir=tmp_path, timeout=WAIT) as lone:
        ready = str(lone.ready_file)
        out = gl("send", ready, "123#GG")
        assert out.returncode == 2 and "not hexadecimal" in out.stderr
        out = gl("send", ready, "123#01", "--timeout", "1")
        assert out.returncode == 1 and "not acknowledged" in out.stderr and "--acker" in out.stderr
    with RigProcess(rig_file, "--acker", workdir=tmp_path, timeout=WAIT) as acked:
        assert gl("send", str(acked.ready_file), "12345678#11.22").returncode == 0
        fd = gl("send", str(acked.ready_file), "123##1" + "11" * 12)
        assert fd.returncode == 1 and "classic CAN" in fd.stderr


def test_replay_of_the_rigs_pcapng_in_every_view(rig: RigProcess, tmp_path: Path) -> None:
    """`run --trace can0=x.pcapng` is read back by --replay: candump lines with absolute stamps, the
    viewer's table, the decoded log (issue 25: 'No read support for unknown log format' before)."""
    ready = str(rig.ready_file)
    for _ in range(3):
        assert gl("send", ready, "321#CAFE").returncode == 0
    trace = next(Path(rig.ready_file).parent.glob("trace.pcapng"))
    time.sleep(0.3)                                                   # the rig flushes every 100 ms
    raw = gl("dump", "--replay", str(trace), "-t", "a", "-f", "321:7FF")
    assert raw.returncode == 0, raw.stderr
    lines = raw.stdout.splitlines()
    assert len(lines) >= 3 and all(re.fullmatch(r" \(\d{10}\.\d{6}\)  can0  321   \[2\]  CA FE", ln) for ln in lines)
    view = gl("monitor", "--replay", str(trace), "--viewer", "-f", "321:7FF")
    row = next(ln for ln in view.stdout.splitlines() if " 321 " in ln)
    assert row.split()[0] == str(len(lines)) and row.endswith("CA FE")
    decoded = gl("monitor", "--replay", str(trace), "--plain")
    assert decoded.returncode == 0 and "321   [2]  CA FE" in decoded.stdout


@pytest.mark.parametrize("name, content, where", [
    ("zeros.asc", b"\0" * 4096, "line 1 (offset 0): a NUL byte"),
    ("garbage.log", b"(1.0) can0 123#00\nthis is not candump\n", "line 2: not a .log line"),
    ("cut.pcap", struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 72, 227) + bytes(10),
     "offset 24: truncated record header"),
    ("noise.pcapng", b"\x13\x37" * 40, "offset 0: not a pcapng file"),
    ("x.unknown", b"abc", "not one the rig writes"),
])
def test_a_bad_trace_is_one_clear_line(tmp_path: Path, name: str, content: bytes, where: str) -> None:
    """A corrupt or foreign trace: exit 2 and one line naming the file and the line or byte offset; no
    traceback, no NUL bytes echoed."""
    path = tmp_path / name
    path.write_bytes(content)
    out = gl("monitor", "--replay", str(path), "--plain")
    assert out.returncode == 2
    err = out.stderr.strip()
    assert "\n" not in err and "Traceback" not in err and "\0" not in err
    assert err.startswith(f"gatewaylab: {path}: ") and where in err, err


def test_decoded_times_count_from_the_start_and_say_so(tmp_path: Path) -> None:
    """Issue 25, one time base: the decoded view counts seconds from the start (a trace in Unix time from
    its first frame) and says so on stderr; --absolute prints Unix time."""
    trace = tmp_path / "unix.log"
    trace.write_text("(1700000000.500000) can0 100#DEADBEEF\n(1700000001.750000) can0 000#0100\n")
    rel = gl("monitor", "--replay", str(trace), "--plain")
    assert rel.returncode == 0, rel.stderr
    assert [ln.split("  ")[0] for ln in rel.stdout.splitlines()] == ["0.000000", "1.250000"]
    assert "times: seconds since the trace's first frame (Unix time 1700000000.500000" in rel.stderr
    absolute = gl("monitor", "--replay", str(trace), "--json", "--absolute")
    assert [json.loads(ln)["t"] for ln in absolute.stdout.splitlines()] == [1700000000.5, 1700000001.75]
