"""A time window of a trace: ``--from`` / ``--to`` of ``gatewaylab dump --replay``, ``monitor --replay`` and
``plot`` (docs/cli.md "A time window of a trace").

Trace time is what ``monitor --replay`` prints: a trace in Unix time (.log, .pcap, ...) counts from its first
frame, a rig's .asc from the rig's start. ``--from T`` / ``--to T``: trace time T; ``--from +S``: S seconds
after the first frame; ``--to +D``: D seconds after the window's start. The window holds the frames with
from <= t < to.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.bus.transport.trace import TimeWindow, Trace, read_trace
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError

#: the rig's clock: frame k (id 0x100 + k) starts at 0.05 + 0.1 k s (k = 0..29)
FRAMES = 30


def _trace(path: Path, epoch: float = 1_700_000_000.0) -> None:
    """Frames 0x100.. 0x11D, one every 100 ms from 50 ms of the rig's clock, recorded by the rig's Trace."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0")
    trace = Trace(bus, path, epoch=epoch)
    sender, _acker = bus.attach("sender"), bus.attach("acker")
    clock.advance(0.05)
    for k in range(FRAMES):
        sender.send(CanFrame(0x100 + k, bytes([k])))
        clock.advance(0.1)
    trace.close()


def _ids(items: list[tuple[object, float]]) -> list[int]:
    return [obj.can_id for obj, _ in items if isinstance(obj, CanFrame)]


def _dump(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "dump", "--replay", *args], capture_output=True,
                          text=True, timeout=120, check=False)


def test_window_forms_select_the_same_frames(tmp_path: Path) -> None:
    """In a Unix-time trace (.log) trace time counts from the first frame (at the rig's 50 ms): frames
    3..5 are at 0.3, 0.4, 0.5 s of trace time. ``--from 0.25 --to 0.55``, ``--from +0.25 --to +0.3``
    and a Unix time ``--from`` select them; in the rig's .asc (relative to the rig's start) the same
    frames are at 0.35..0.55 s, so ``--from 0.3 --to 0.6`` selects them there and ``+0.25/+0.3`` still
    does (relative to the first frame)."""
    log, asc = tmp_path / "run.log", tmp_path / "run.asc"
    _trace(log)
    _trace(asc)
    items_log, items_asc = read_trace(log), read_trace(asc)
    first = items_log[0][1]
    assert _ids(list(TimeWindow.parse("0.25", "0.55").select(items_log))) == [0x103, 0x104, 0x105]
    assert _ids(list(TimeWindow.parse("+0.25", "+0.3").select(items_log))) == [0x103, 0x104, 0x105]
    assert _ids(list(TimeWindow.parse(f"{first + 0.25:.6f}", "+0.3").select(items_log))) == [0x103, 0x104, 0x105]
    assert _ids(list(TimeWindow.parse("0.3", "0.6").select(items_asc))) == [0x103, 0x104, 0x105]
    assert _ids(list(TimeWindow.parse("+0.25", "+0.3").select(items_asc))) == [0x103, 0x104, 0x105]
    assert _ids(list(TimeWindow.parse("2.75", None).select(items_log))) == [0x11C, 0x11D]     # to the end
    assert _ids(list(TimeWindow.parse(None, "+0.15").select(items_log))) == [0x100, 0x101]   # from the start


@pytest.mark.parametrize(("start", "end", "says"), [
    ("abc", None, "--from wants seconds"),
    ("-1", None, "--from wants seconds"),
    (None, "+0", "not after"),
    ("2", "1.5", "not after"),
])
def test_bad_windows_are_refused(start: str | None, end: str | None, says: str) -> None:
    """A bound that is not seconds >= 0, or a window that ends before it starts, is a ConfigError (exit 2)."""
    with pytest.raises(ConfigError, match=says):
        TimeWindow.parse(start, end)


def test_dump_and_monitor_replay_window(tmp_path: Path) -> None:
    """From a shell: ``dump --replay run.log --from +0.25 --to +0.3`` prints frames 0x103..0x105 only;
    ``monitor --replay --plain`` prints them with their trace times (0.3 .. 0.5 s, not restarted at 0);
    a bad bound, an empty window and a window on a live bus exit 2 with one line."""
    log = tmp_path / "run.log"
    _trace(log)
    dump = _dump(str(log), "--from", "+0.25", "--to", "+0.3")
    assert dump.returncode == 0, dump.stderr
    assert [line.split()[1] for line in dump.stdout.splitlines()] == ["103", "104", "105"]
    monitor = subprocess.run([sys.executable, "-m", "gatewaylab", "monitor", "--replay", str(log), "--plain",
                              "--from", "0.25", "--to", "0.55"], capture_output=True, text=True, timeout=120,
                             check=False)
    assert monitor.returncode == 0, monitor.stderr
    times = [float(line.split()[0]) for line in monitor.stdout.splitlines() if line.strip()]
    assert len(times) == 3 and 0.29 < times[0] < 0.31 and 0.49 < times[-1] < 0.51, monitor.stdout
    for bad in (["--from", "x"], ["--from", "2", "--to", "1"]):
        out = _dump(str(log), *bad)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and "Traceback" not in out.stderr
    live = subprocess.run([sys.executable, "-m", "gatewaylab", "dump", "unix:/nonexistent.sock", "--from", "1"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert live.returncode == 2 and "--replay" in live.stderr


def test_plot_window(tmp_path: Path) -> None:
    """``plot --from +0.25 --to +0.3``: the load bins cover 0.3 .. 0.5 s of trace time only; an empty
    window is one line, exit 2."""
    from gatewaylab.cli.plot import read_trace as picture_of
    log = tmp_path / "run.log"
    _trace(log)
    picture = picture_of(log, window=TimeWindow.parse("+0.25", "+0.3"))
    busy = [t for t, v in picture.load if v > 0]       # 10 ms bins: a frame at 0.3 s may fall into 0.29's
    assert busy == pytest.approx([0.3, 0.4, 0.5], abs=0.0101)
    assert picture.load[0][0] >= 0.289 and picture.end is not None and picture.end < 0.51
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "plot", str(log), "--from", "50",
                          "-o", str(tmp_path / "w.svg")], capture_output=True, text=True, timeout=180, check=False)
    assert out.returncode == 2 and "no frame between" in out.stderr
