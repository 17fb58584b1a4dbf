"""CAN FD frames without data in the rig's ``.asc`` traces replay (docs/monitor.md "CAN FD frames without data
in .asc traces").

ISO 11898-1:2015 10.4.2.2 / 10.4.2.4: a CAN FD frame has no remote form (its RRS bit is always dominant) and
its data length code may be 0. Vector's ASC ``CANFD`` event carries the frame's flags (EDL 0x1000: a CAN FD
frame, BRS 0x2000, ESI 0x4000, remote 0x0010 for a classic frame on an FD channel); python-can's ASCReader
ignores them and takes every ``CANFD`` line with data length 0 for a remote frame, so the rig's own trace
of ``123##0`` could not be read (``dump --replay``, ``monitor --replay``, ``plot``: nothing shown, exit 2).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import can

from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.transport.trace import read_trace
from gatewaylab.rig.process import RigProcess

RIG_FD = """
clock = "realtime"

[[bus]]
name = "can0"
bitrate = 1000000
data_bitrate = 5000000
"""

#: what the test sends: two FD frames without data (one with BRS), one with a byte, a classic one
SENT = [
    can.Message(arbitration_id=0x123, is_extended_id=False, is_fd=True, data=b""),
    can.Message(arbitration_id=0x124, is_extended_id=False, is_fd=True, bitrate_switch=True, data=b""),
    can.Message(arbitration_id=0x125, is_extended_id=False, is_fd=True, data=b"\x01"),
    can.Message(arbitration_id=0x126, is_extended_id=False, data=b""),
]


def _gatewaylab(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", *args], capture_output=True, text=True,
                          timeout=180, check=False)


def test_rig_asc_trace_with_empty_fd_frames_replays(tmp_path: Path) -> None:
    """``gatewaylab run --trace can0=run.asc`` on a CAN FD bus, python-can sends ``123##0``, ``124##1``
    (BRS), ``125##001`` and ``126#``; after the rig stopped, the trace reads back with all four frames as
    sent (FD, no data, BRS kept; no remote frame), and ``dump --replay``, ``monitor --replay --plain`` and
    ``plot`` read it (exit 0, the frames listed)."""
    trace = tmp_path / "run.asc"
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG_FD)
    with RigProcess(rig_file, "--trace", f"can0={trace}", workdir=tmp_path) as rig:
        with can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as rx, \
                can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as tx:
            for msg in SENT:
                tx.send(msg)
            got = []
            deadline = time.monotonic() + 20
            while len(got) < len(SENT) and time.monotonic() < deadline:
                msg = rx.recv(0.5)
                if msg is not None:
                    got.append(msg)
            assert [m.arbitration_id for m in got] == [0x123, 0x124, 0x125, 0x126]
        assert rig.stop(20) == 0
    frames = [obj for obj, _ in read_trace(trace)]
    assert frames == [CanFrame(0x123, b"", fd=True), CanFrame(0x124, b"", fd=True, brs=True),
                      CanFrame(0x125, b"\x01", fd=True), CanFrame(0x126, b"")]

    dump = _gatewaylab("dump", "--replay", str(trace))
    assert dump.returncode == 0, dump.stderr
    lines = dump.stdout.splitlines()
    assert [line.split()[1] for line in lines] == ["123", "124", "125", "126"], dump.stdout
    assert "[00]" in lines[0] and "[00]" in lines[1]            # candump's FD length form: no data
    monitor = _gatewaylab("monitor", "--replay", str(trace), "--plain")
    assert monitor.returncode == 0, monitor.stderr
    assert all(f"{cid:03X}" in monitor.stdout or f"0x{cid:03X}" in monitor.stdout
               for cid in (0x123, 0x124, 0x125, 0x126)), monitor.stdout
    plot = _gatewaylab("plot", str(trace), "-o", str(tmp_path / "run.svg"))
    assert plot.returncode == 0, plot.stderr
    assert "bus load" in plot.stdout


ASC_HEADER = """date Sun Nov 29 03:17:36.643 2026
base hex  timestamps absolute
internal events logged
Begin Triggerblock Sun Nov 29 03:17:36.640 2026
"""


def test_asc_canfd_lines_of_length_zero_by_their_flags(tmp_path: Path) -> None:
    """The ``CANFD`` lines of length 0 are read by their flags field: EDL -> CAN FD frame of length 0 (BRS
    and ESI from their columns), no EDL + remote flag -> classic remote frame with the line's DLC, no EDL
    and no remote flag -> classic frame without data; a symbolic name before the BRS column is skipped;
    a line that ends before its flags is a CAN FD frame (CAN FD has no remote frames)."""
    path = tmp_path / "vector.asc"
    path.write_text(ASC_HEADER + "\n".join([
        " 0.001000 CANFD   1 Rx        123                                   0 0 0  0    0 0   1000 0 0 0 0 0",
        " 0.002000 CANFD   1 Rx        124                                   1 1 0  0    0 0   7000 0 0 0 0 0",
        " 0.003000 CANFD   1 Rx        125                                   0 0 8  0    0 0     10 0 0 0 0 0",
        " 0.004000 CANFD   1 Rx        126                                   0 0 0  0    0 0      0 0 0 0 0 0",
        " 0.005000 CANFD   1 Rx        127  Motor_Cmd                        0 0 0  0    0 0   1000 0 0 0 0 0",
        " 0.006000 CANFD   1 Rx        128                                   0 0 0  0    0",
        " 0.007000 CANFD   1 Rx        129                                   0 0 1  1 05 0 0   1000 0 0 0 0 0",
        "End TriggerBlock", ""]))
    frames = [obj for obj, _ in read_trace(path)]
    assert frames == [
        CanFrame(0x123, b"", fd=True),
        CanFrame(0x124, b"", fd=True, brs=True, esi=True),
        CanFrame(0x125, b"", rtr=True, dlc=8),
        CanFrame(0x126, b""),
        CanFrame(0x127, b"", fd=True),
        CanFrame(0x128, b"", fd=True),
        CanFrame(0x129, b"\x05", fd=True),
    ]
