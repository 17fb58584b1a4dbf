"""The ``ecanlite`` rig kind: validation, segment membership, ready file, flash under the state dir."""

from __future__ import annotations

from pathlib import Path

import pytest

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.ecanlite.image import PRODUCT_CODE, VENDOR_ID
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "simulated"
[[bus]]
name = "can0"
bitrate = 1000000
data_bitrate = 5000000
[[bus]]
name = "can1"
bitrate = 500000
[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can0", "can1"]
serial = 42
{extra}
[[device]]
kind = "ethercat_io"
name = "io"
[ethercat]
interface = "gl-none"
"""


def _rig(tmp_path: Path, extra: str = "") -> Rig:
    path = tmp_path / "rig.toml"
    path.write_text(RIG.format(extra=extra))
    return Rig.from_file(path, state_dir=tmp_path / "state")


def test_ecanlite_joins_the_segment_and_the_ready_file(tmp_path: Path) -> None:
    """Issue 10 'MCAN channels': channels[k] = MCAN k, the rest unconnected; listed in ethercat.slaves."""
    with _rig(tmp_path) as rig:
        rig.start()
        info = rig.ready_info()
        assert info["ethercat"]["slaves"][0] == {"name": "ecan", "position": 0, "vendor_id": VENDOR_ID,
                                                 "product_code": PRODUCT_CODE}
        assert info["ecanlite"]["ecan"]["channels"] == ["can0", "can1"]
        assert info["ecanlite"]["ecan"]["flash"] == str(tmp_path / "state" / "ecan.flash")
        dev = next(p for p in rig.participants if p.name == "ecan")
        channels = dev.device.model.channels  # type: ignore[attr-defined]
        assert [ch.controller is not None for ch in channels] == [True, True, False, False]
        segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
        m = Master(rig.clock, segment)
        # the SII carries the product name, the rig name is the participant's
        assert [(s.name, s.serial) for s in m.scan()] == [("ECAN-Lite", 42), ("io", 0)]


@pytest.mark.parametrize("old, new, match", [
    ('channels = ["can0", "can1"]', 'channels = ["can0", "can1", "can0", "can1", "can0"]', "channels"),
    ("serial = 42", "serial = -1", "serial"),
    ("serial = 42", "colour = 1", "colour"),
])
def test_bad_sections_are_one_line_errors(tmp_path: Path, old: str, new: str, match: str) -> None:
    """The shared validator: unknown keys, ranges, more than 4 channels are refused before anything exists."""
    path = tmp_path / "rig.toml"
    path.write_text(RIG.format(extra="").replace(old, new))
    with pytest.raises(ConfigError, match=match):
        Rig.from_file(path, state_dir=tmp_path / "state")


def test_unknown_bus_is_refused(tmp_path: Path) -> None:
    """channels must name declared buses."""
    path = tmp_path / "rig.toml"
    path.write_text(RIG.format(extra="").replace('["can0", "can1"]', '["can0", "can9"]'))
    with pytest.raises(ConfigError, match="can9"):
        Rig.from_file(path, state_dir=tmp_path / "state")
