"""``gatewaylab plot TRACE`` (issue 14, "Watch": PNG or SVG of bus load over time and of decoded drive values
-- position, velocity, statusword bits, mode -- from a trace file)."""

import struct
import subprocess
import sys
import zlib
from pathlib import Path

import can
from canopen_monitor_kit import record_session

from gatewaylab.cli.plot import read_trace
from gatewaylab.devices.canopen_drive.objects import build_object_dictionary


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


def _motion_trace(path: Path) -> None:
    """A drive (node 2) booting and moving to negative positions, its TPDO1 (statusword + position,
    the drive's default mapping) every 10 ms, one SDO read of 0x6064, recorded by the rig's Trace."""
    from gatewaylab.bus import CanFrame, VirtualBus
    from gatewaylab.bus.transport.trace import Trace
    from gatewaylab.common.clock import SimulatedClock
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0")
    trace = Trace(bus, path)
    drive, master = bus.attach("drive"), bus.attach("master")
    drive.send(CanFrame(0x702, b"\x00"))
    clock.advance(0.01)
    for k in range(20):
        drive.send(CanFrame(0x182, struct.pack("<Hi", 0x1237, -1000 * k)))
        clock.advance(0.01)
    master.send(CanFrame(0x602, bytes.fromhex("4064600000000000")))
    clock.advance(0.001)
    drive.send(CanFrame(0x582, b"\x43\x64\x60\x00" + struct.pack("<i", -19000)))
    clock.advance(0.01)
    trace.close()


def test_plot_without_node_decodes_signed_tpdo_motion_and_fills_velocity(tmp_path: Path) -> None:
    """Issue 25: without --node every node of the trace is read with the drive dictionary (CiA 402
    0x6064 is INTEGER32): negative positions stay negative (not ~4.29e9), the TPDO-carried motion is
    plotted, and the velocity panel holds the derivative of position where no 0x606C was carried.
    The arrays handed to matplotlib are checked, not pixels."""
    from gatewaylab.cli.plot import panels
    trace = tmp_path / "motion.pcapng"
    _motion_trace(trace)
    picture = read_trace(trace)
    figure = panels(picture)
    assert [p.ylabel for p in figure] == ["bus load %", "node 2\nposition", "velocity\n(from position)",
                                         "statusword"]
    (_, _, ys), = figure[1].lines
    assert min(ys) == -19000 and max(ys) == 0 and len(ys) >= 20
    assert all(abs(v) < 1e6 for v in ys)
    (_, _, vy), = figure[2].lines
    assert len(vy) >= 18 and all(-100_000 * 1.01 < v < -100_000 * 0.99 for v in vy)   # -1000 per 10 ms
    bits = {label: set(y) for label, _, y in figure[3].lines}
    assert bits["operation_enabled"] == {2 * 1.3 + 1} and bits["fault"] == {3 * 1.3}   # 0x1237: enabled, no fault
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "plot", str(trace), "-o", str(tmp_path / "m.svg")],
                         capture_output=True, text=True, timeout=180, check=False)
    assert out.returncode == 0 and "node(s) 2" in out.stdout, out.stderr
