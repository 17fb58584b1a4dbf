"""``gatewaylab play TARGET TRACE`` (docs/cli.md "Playing a trace onto a bus: gatewaylab play"): a trace sent
back onto a running rig's bus as can-utils' canplayer does -- the frames in trace order with their content,
their spacing scaled by ``--speed``, ``--loop N`` times, through a candump filter, from a time window, to
``--bus`` or channel by channel (``--map CHANNEL=BUS``, canplayer -I). Driven as a user does: ``gatewaylab
run`` in a child process, ``gatewaylab play`` in another, python-can receivers counting what arrives. No
timing asserts: the effect of ``--speed`` is a ratio of the receivers' bus timestamps with a wide margin.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"

[[bus]]
name = "can0"
data_bitrate = 5000000

[[bus]]
name = "can1"

[[bus]]
name = "lonely"
"""

#: a candump .log of two interfaces: can0 sends 0x100..0x109 every 100 ms (the 6th a CAN FD frame),
#: vcan1 sends 0x200 and 0x201 in between, plus one error frame (not sent: a client cannot)
T0 = 1_700_000_000.0


def _log_text() -> str:
    lines = []
    for k in range(10):
        data = f"{k:02X}" * min(k + 1, 8) if k != 5 else ""
        frame = f"1{k:02X}#{data}" if k != 5 else "105##1" + "AB" * 12
        lines.append(f"({T0 + 0.1 * k:.6f}) can0 {frame}")
        if k in (3, 6):
            lines.append(f"({T0 + 0.1 * k + 0.05:.6f}) vcan1 2{k // 6:02X}#C0FFEE")
    lines.insert(2, f"({T0 + 0.15:.6f}) can0 20000080#0000000000000000")   # an error frame (candump -e)
    return "\n".join(lines) + "\n"


#: (id, data, fd) of the can0 frames of the trace, in order
CAN0 = [(0x100 + k, bytes([k] * min(k + 1, 8)) if k != 5 else bytes([0xAB] * 12), k == 5) for k in range(10)]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    folder = tmp_path_factory.mktemp("play")
    (folder / "rig.toml").write_text(RIG)
    with RigProcess(folder / "rig.toml", workdir=folder) as process:
        yield process


@pytest.fixture(scope="module")
def trace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("trace") / "two.log"
    path.write_text(_log_text())
    return path


class Receivers:
    """python-can clients on can0 and can1 (they acknowledge, as any node does) collecting frames."""

    def __init__(self, rig: RigProcess) -> None:
        self.buses = {name: can.Bus(interface="gatewaylab", channel=rig.endpoint(name)) for name in ("can0", "can1")}

    def collect(self, name: str, count: int, timeout: float = 30.0) -> list[can.Message]:
        got: list[can.Message] = []
        deadline = time.monotonic() + timeout
        while len(got) < count and time.monotonic() < deadline:
            msg = self.buses[name].recv(0.2)
            if msg is not None and not msg.is_error_frame:
                got.append(msg)
        extra = self.buses[name].recv(0.3)                 # nothing more arrives
        assert extra is None, f"unexpected frame {extra}"
        return got

    def close(self) -> None:
        for bus in self.buses.values():
            bus.shutdown()


@pytest.fixture
def rx(rig: RigProcess) -> Iterator[Receivers]:
    receivers = Receivers(rig)
    yield receivers
    receivers.close()


def _play(rig: RigProcess, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "play", str(rig.ready_file), *args],
                          capture_output=True, text=True, timeout=120, check=False)


def _content(msgs: list[can.Message]) -> list[tuple[int, bytes, bool]]:
    return [(m.arbitration_id, bytes(m.data), m.is_fd) for m in msgs]


def test_play_sends_the_trace_in_order_and_speed_scales_its_spacing(rig: RigProcess, trace: Path,
                                                                    rx: Receivers) -> None:
    """Without --map every frame goes to --bus (can0 by default): the 10 can0 frames and the 2 vcan1 frames in
    trace order with their content (the FD frame with BRS), not the error frame; exit 0 and one summary line.
    --speed 5: the frames arrive with the same order and content, their first-to-last span on the bus's
    clock well under that of the original pace (0.9 s of trace: >= ~0.9 s at speed 1, ~0.18 s at speed 5)."""
    spans = {}
    for speed in ("1", "5"):
        out = _play(rig, str(trace), "--speed", speed)
        assert out.returncode == 0, out.stderr
        assert out.stdout == "two.log: 12 frames sent (can0: 12); not sent: 1 error frames\n"
        got = rx.collect("can0", 12)
        ids = [m.arbitration_id for m in got]
        assert ids == [0x100, 0x101, 0x102, 0x103, 0x200, 0x104, 0x105, 0x106, 0x201, 0x107, 0x108, 0x109]
        assert [c for c in _content(got) if c[0] < 0x200] == CAN0
        assert next(m for m in got if m.arbitration_id == 0x105).bitrate_switch
        spans[speed] = got[-1].timestamp - got[0].timestamp
    assert spans["1"] > 0.7 and spans["5"] < 0.6 * spans["1"], spans


def test_loop_filter_window_and_no_timing(rig: RigProcess, trace: Path, rx: Receivers) -> None:
    """-t --loop 3 -f 100:7F0 (ids 0x100..0x10F, candump syntax) --from +0.2 --to +0.5 (from 0.2 s after the
    first frame, for 0.5 s): frames 0x102..0x106 three times over, in order; 0x200 and 0x201 filtered out."""
    out = _play(rig, str(trace), "-t", "--loop", "3", "-f", "100:7F0", "--from", "+0.2", "--to", "+0.5")
    assert out.returncode == 0, out.stderr
    assert out.stdout == "two.log: 15 frames sent in 3 loops (can0: 15); not sent: 2 filtered out\n"
    got = rx.collect("can0", 15)
    assert [m.arbitration_id for m in got] == [0x102, 0x103, 0x104, 0x105, 0x106] * 3


def test_map_sends_channels_to_their_buses(rig: RigProcess, trace: Path, rx: Receivers) -> None:
    """--map vcan1=can1 --map can0=can0 (canplayer -I): each channel's frames on its bus, in order; with only
    --map can0=can1 the vcan1 frames are not played (the summary says so)."""
    out = _play(rig, str(trace), "-t", "--map", "vcan1=can1", "--map", "can0=can0")
    assert out.returncode == 0, out.stderr
    assert _content(rx.collect("can0", 10)) == CAN0
    assert [m.arbitration_id for m in rx.collect("can1", 2)] == [0x200, 0x201]
    out = _play(rig, str(trace), "-t", "--map", "can0=can1", "-f", "100:7FC")
    assert out.returncode == 0, out.stderr
    assert "2 of channel vcan1 (not in --map)" in out.stdout
    assert [m.arbitration_id for m in rx.collect("can1", 4)] == list(range(0x100, 0x104))


def test_replays_every_format_the_rig_writes(rig: RigProcess, tmp_path: Path, rx: Receivers) -> None:
    """A trace the rig recorded (gatewaylab run --trace, here the same Trace class) in each format plays back
    with its frames: .log, .asc (also a CAN FD frame without data), .blf, .txt, .pcap, .pcapng."""
    from gatewaylab.bus import CanFrame, VirtualBus
    from gatewaylab.bus.transport.trace import Trace
    from gatewaylab.common.clock import SimulatedClock
    sent = [CanFrame(0x300, b"\x01\x02"), CanFrame(0x301, b"", fd=True), CanFrame(0x12345678, b"\xFF", extended=True)]
    for suffix in (".log", ".asc", ".blf", ".txt", ".pcap", ".pcapng"):
        clock = SimulatedClock()
        bus = VirtualBus(clock, "can0", data_bitrate=5_000_000)
        path = tmp_path / f"rec{suffix}"
        recorder = Trace(bus, path, epoch=T0)
        node, _acker = bus.attach("node"), bus.attach("acker")
        for frame in sent:
            node.send(frame)
            clock.advance(0.01)
        recorder.close()
        out = _play(rig, str(path), "-t")
        assert out.returncode == 0, (suffix, out.stderr)
        got = rx.collect("can0", 3)
        assert [(m.arbitration_id, bytes(m.data), m.is_fd, m.is_extended_id) for m in got] == [
            (0x300, b"\x01\x02", False, False), (0x301, b"", True, False), (0x12345678, b"\xFF", False, True)], suffix


def test_errors(rig: RigProcess, trace: Path, tmp_path: Path) -> None:
    """A bus nobody else is on: the frames are not acknowledged, exit 1 naming --acker; a CAN FD frame onto a
    classic bus is refused, exit 1. Usage errors exit 2
    with one line naming the problem (argparse's own after its usage lines): a missing trace, a bad --map,
    a bad filter, --speed 0, a bus the ready file lacks."""
    out = _play(rig, str(trace), "-t", "--bus", "lonely", "-f", "100:7FF")
    assert out.returncode == 1 and "not acknowledged" in out.stderr and "--acker" in out.stderr, out.stderr
    out = _play(rig, str(trace), "-t", "--bus", "can1", "-f", "105:7FF")     # CAN FD onto a classic bus
    assert out.returncode == 1 and "classic CAN" in out.stderr, out.stderr
    for args in ([str(tmp_path / "none.log")], [str(trace), "--map", "can0"], [str(trace), "-f", "xyz"],
                 [str(trace), "--speed", "0"], [str(trace), "--bus", "can9"]):
        out = _play(rig, *args)
        assert out.returncode == 2, (args, out.stderr)
        last = out.stderr.strip().splitlines()[-1]
        assert last.startswith("gatewaylab") and "Traceback" not in out.stderr, out.stderr
