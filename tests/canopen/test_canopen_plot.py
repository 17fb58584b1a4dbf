"""``gatewaylab plot TRACE`` (issue 14, "Watch": PNG or SVG of bus load over time and of decoded drive values
-- position, velocity, statusword bits, mode -- from a trace file)."""

import struct
import subprocess
import sys
import zlib
from pathlib import Path

import can
from canopen_monitor_kit import record_session

from gatewaylab.canopen.drive import build_object_dictionary
from gatewaylab.canopen.plot_cli import read_trace


def write_trace(path: Path) -> None:
    session = record_session()
    with can.Logger(str(path)) as writer:   # python-can picks the writer from the suffix
        for frame, t in session.frames:
            writer.on_message_received(frame.to_message(1_700_000_000 + t, "can0"))


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def test_series_are_the_monitors_decoding(tmp_path: Path) -> None:
    """The statusword of drive 2 walks 0x0240 -> 0x0231 -> 0x0233 -> 0x0637 (CiA 402 transitions 2, 3, 4)
    as its TPDO1 says; the load is the bit-count model over 10 ms bins, never above 100 %."""
    trace = tmp_path / "session.asc"
    write_trace(trace)
    picture = read_trace(trace, {2: build_object_dictionary(0, 2)})
    words = [v for _, v in picture.nodes[2].statusword]
    assert words[:4] == [0x0240, 0x0231, 0x0233, 0x0637]
    assert picture.nodes[2].position and picture.nodes[2].position[0][1] == 0
    assert 0 < max(v for _, v in picture.load) <= 100.0
    assert abs(picture.load[1][0] - 0.01) < 1e-9


def test_cli_writes_png_and_svg(tmp_path: Path) -> None:
    """From a shell: a PNG with real pixels (not one colour) and an SVG document."""
    trace = tmp_path / "session.blf"
    write_trace(trace)
    png, svg = tmp_path / "out.png", tmp_path / "out.svg"
    for out in (png, svg):
        done = subprocess.run([sys.executable, "-m", "gatewaylab", "plot", str(trace), "--node", "2", "-o", str(out)],
                              capture_output=True, text=True, timeout=180, check=False)
        assert done.returncode == 0, done.stderr
        assert "node(s) 2" in done.stdout
    width, height = png_size(png.read_bytes())
    assert width >= 600 and height >= 400
    assert len(zlib.compress(png.read_bytes())) > 5000    # drawn lines, not a blank canvas
    assert svg.read_text().lstrip().startswith("<?xml") and "<svg" in svg.read_text()
    bad = subprocess.run([sys.executable, "-m", "gatewaylab", "plot", str(trace), "-o", str(tmp_path / "x.jpg")],
                         capture_output=True, text=True, timeout=60, check=False)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
