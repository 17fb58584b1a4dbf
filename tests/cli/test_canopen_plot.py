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
from gatewaylab.devices.canopen_drive.device import build_object_dictionary


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


def _pp_move_trace(path: Path, profile_velocity: int, target: int) -> None:
    """Drive 2 on a simulated 1 Mbit/s bus, NMT Operational (event-driven TPDO1: statusword + position
    every control period while it moves), a PP move to ``target`` at ``profile_velocity`` (0x6081), on a
    busy bus: another node sends 12 frames of higher priority (id 0x010) every 4.7 ms, so TPDO1s wait
    and then leave back to back (~115 us apart, their positions 1 ms apart), recorded by the rig's Trace."""
    from gatewaylab.bus import CanFrame, VirtualBus
    from gatewaylab.bus.transport.trace import Trace
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.canopen_drive.device import Drive
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0")
    trace = Trace(bus, path)
    master, busy = bus.attach("master"), bus.attach("busy")
    drive = Drive(clock, bus, 2, 0x1002)
    drive.start()
    clock.advance(0.01)
    master.send(CanFrame(0x000, bytes([1, 2])))          # NMT start node 2

    def write(index: int, fmt: str, value: int) -> None:
        drive.node.write(index, 0, struct.pack("<" + fmt, value))
    write(0x6060, "b", 1)
    write(0x6081, "I", profile_velocity)
    for controlword in (0x06, 0x07, 0x0F):
        write(0x6040, "H", controlword)
    write(0x607A, "i", target)
    write(0x6040, "H", 0x1F)

    def burst() -> None:
        for _ in range(12):
            busy.send(CanFrame(0x010, bytes(8)))
    clock.call_every(0.0047, burst)
    clock.advance(target / profile_velocity + 0.5)
    trace.close()


def test_velocity_from_position_is_the_profile_velocity(tmp_path: Path) -> None:
    """A PP move at 0x6081 = 20,000 inc/s (CiA 402 profile position: the trapezoid's plateau runs at the
    profile velocity) on a busy bus: the derived velocity's plateau is 20,000 within 1 %, and nowhere
    (ramps, TPDOs queued back to back) above 2 % more; the neighbour-to-neighbour quotient reached
    174,038. No 0x606C in the trace (TPDO1 carries statusword + position), so the panel is derived."""
    from gatewaylab.cli.plot import panels
    trace = tmp_path / "move.log"
    _pp_move_trace(trace, 20_000, 30_000)
    picture = read_trace(trace)
    assert not picture.nodes[2].velocity
    figure = panels(picture)
    derived = next(p for p in figure if p.ylabel == "velocity\n(from position)")
    (_, xs, ys), = derived.lines
    moving = [t for t, v in picture.nodes[2].position if v != 0]
    start, end = moving[0], moving[-1]
    assert 1.45 < end - start < 1.7                      # 30,000 inc at 20,000 inc/s + ramps
    plateau = [v for t, v in zip(xs, ys, strict=True) if start + 0.3 < t < end - 0.3]
    assert len(plateau) > 500
    assert all(abs(v - 20_000) < 200 for v in plateau), (min(plateau), max(plateau))
    assert max(ys) < 20_400 and min(ys) > -400
    assert ys[-1] == 0.0 or abs(ys[-1]) < 400          # the axis ends at rest
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "plot", str(trace), "-o", str(tmp_path / "m.svg")],
                         capture_output=True, text=True, timeout=180, check=False)
    assert out.returncode == 0 and "node(s) 2" in out.stdout, out.stderr


def test_derivative_over_a_stop_and_a_slow_move() -> None:
    """The derived velocity of position changes: 1000 inc/s for 0.2 s (a change every ms), a 1 s stop, then
    a slow move of 1 inc every 100 ms: the move reads 1000, the stop 0 from where it began (not a ramp from
    1000 down), the slow move 10 inc/s (a change per 100 ms is a real speed, not a stop)."""
    from gatewaylab.cli.plot import derivative
    points = [(k * 0.001, k) for k in range(201)]
    points += [(1.2 + k * 0.1, 200 + k) for k in range(1, 6)]
    derived = derivative(points)
    assert all(abs(v - 1000) < 1e-6 for t, v in derived if t < 0.1999)
    at_stop = [v for t, v in derived if 0.2 <= t <= 1.3 and v < 5]
    assert at_stop and all(abs(v - 1 / 1.1) < 1e-6 for v in at_stop)       # 1 inc over the 1.1 s gap
    assert (0.2, at_stop[0]) in derived                                       # drawn from the stop's start
    assert all(abs(v - 10) < 1e-6 for t, v in derived if t > 1.35)
