"""`gatewaylab.rig.process.RigProcess`: the one way tests, the soak and the conformance run start a
real-time rig in another process (issue 15: a failed start cleans up and says why; SIGTERM stops the
rig and removes its folder)."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.process import RigProcess, RigStartTimeout


def test_started_rig_serves_its_endpoint_and_stops_on_sigterm(tmp_path: Path) -> None:
    """The ready file's endpoint is served once RigProcess returns; stop() ends the rig with exit 0
    (SIGTERM handled) and its state folder is gone (docs/rig.md 'Errors and exit codes')."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text('[[bus]]\nname = "can0"\n')
    with RigProcess(rig_file, "--acker", workdir=tmp_path) as rig:
        endpoint = rig.endpoint("can0")
        folder = Path(endpoint.removeprefix("unix:")).parent
        with can.Bus(interface="gatewaylab", channel=endpoint) as bus:
            bus.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        assert folder.is_dir()
        assert rig.stop() == 0
    assert not folder.exists()


def test_a_rig_that_cannot_start_raises_with_its_one_line_reason(tmp_path: Path) -> None:
    """A rig file error exits 2 with one line naming the file and key; RigProcess reports that line as a
    ConfigError (docs/testing-your-master.md: a wrong rig is a ConfigError, not a start that timed out)."""
    rig_file = tmp_path / "bad.toml"
    rig_file.write_text('[[bus]]\nname = "can0"\nbitrate = "fast"\n')
    with pytest.raises(ConfigError, match=r"^\S*bad\.toml \[\[bus\]\] #1 \(can0\): bitrate must be") as caught:
        RigProcess(rig_file, workdir=tmp_path, timeout=30)
    assert not isinstance(caught.value, RigStartTimeout)
