"""An empty rig file (docs/rig.md "A minimal rig"): a rig that declares nothing to run -- no bus, no
device -- is refused (exit 2) with what a minimal rig looks like, instead of a rig of nothing that runs
without a word."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.config import MINIMAL_RIG, parse_rig


@pytest.mark.parametrize("text", ["", "\n# nothing yet\n", 'clock = "realtime"\n', '[rig]\nclock = "simulated"\n'])
def test_gatewaylab_run_refuses_a_rig_that_declares_nothing(tmp_path: Path, text: str) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text(text)
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "run", str(rig)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2, out.stdout + out.stderr
    assert out.stdout == ""                               # nothing started: no banner
    err = out.stderr.strip()
    assert err == f"gatewaylab: {rig}: the rig declares nothing to run (no [[bus]], no device); {MINIMAL_RIG}"


def test_the_minimal_rig_the_message_shows_runs() -> None:
    """The two lines the message names are a rig that loads: one bus, nothing else."""
    config = parse_rig(tomllib.loads('[[bus]]\nname = "can0"\n'), "minimal.toml")
    assert [b.name for b in config.buses] == ["can0"] and '[[bus]] and name = "can0"' in MINIMAL_RIG


def test_a_rig_without_buses_but_with_devices_is_not_empty() -> None:
    """An EtherCAT-only rig has no CAN bus and is a rig all the same."""
    config = parse_rig({"ethercat": {"interface": "gl-ecat"}}, "ecat.toml")
    assert config.buses == () and config.ethercat is not None
    with pytest.raises(ConfigError, match=r"^ecat.toml: the rig declares nothing to run"):
        parse_rig({"clock": "simulated"}, "ecat.toml")
