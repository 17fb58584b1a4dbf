"""Two writers of one trace file (issue 25): the second is refused with a clear error instead of
truncating the first one's file into a sparse file of NULs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.bus.transport.trace import Trace, read_trace
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.process import RigProcess


@pytest.mark.parametrize("suffix", [".log", ".pcapng"])
def test_a_locked_trace_file_is_refused_until_its_writer_closes(tmp_path: Path, suffix: str) -> None:
    """flock(2) on the file before anything truncates it: a second Trace of the same path (another bus,
    another rig) raises ConfigError naming the file; the first one's frames stay intact."""
    clock = SimulatedClock()
    path = tmp_path / f"t{suffix}"
    a, b = VirtualBus(clock, "a"), VirtualBus(clock, "b")
    first = Trace(a, path)
    a.attach("y")
    a.attach("x").send(CanFrame(0x123, b"\x01"))
    clock.advance(0.2)
    with pytest.raises(ConfigError, match=f"trace file {path} is being written by another rig"):
        Trace(b, path)
    first.close()
    assert [str(f) for f, _ in read_trace(path)] == ["123#01"]
    Trace(b, path).close()             # free again


def test_a_second_rig_on_the_same_trace_file_exits_with_a_usage_error(tmp_path: Path) -> None:
    """`gatewaylab run --trace can0=x.log` while another rig records x.log: exit 2, one line."""
    trace = tmp_path / "shared.log"
    with RigProcess(None, "--trace", f"can0={trace}", workdir=tmp_path, timeout=60):
        out = subprocess.run([sys.executable, "-m", "gatewaylab", "run", "--trace", f"can0={trace}"],
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 2
        assert out.stderr.strip() == (f"gatewaylab: trace file {trace} is being written by another rig (it holds "
                                      "the file's lock); give each rig its own --trace file")
    assert b"\0" not in trace.read_bytes()
