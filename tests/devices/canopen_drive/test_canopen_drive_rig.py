"""``[[drive]]`` rig sections (issue 3 'Rig file'; docs/architecture.md 'The rig')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.canopen_drive.rig import create_drive
from gatewaylab.od.eds import import_eds
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig


def test_rig_file_builds_drives(tmp_path: Path) -> None:
    """A rig file with a configured and an unconfigured drive: the configured one boots into
    Pre-operational with its node-ID, the other waits for LSS (node-ID 0xFF); the ready file lists each
    drive with its EDS (issue 14, the monitor's dictionaries "from the rig")."""
    config = parse_rig({
        "clock": "simulated",
        "bus": [{"name": "can0", "endpoint": "none"}],
        "drive": [{"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"},
                  {"bus": "can0", "serial": 0x1003}],
    })
    rig = Rig(config, state_dir=tmp_path, endpoints=False)
    try:
        drives = [p for p in rig.participants if isinstance(p, Drive)]
        assert [d.name for d in drives] == ["axis2", "drive-1003"]
        for d in drives:
            d.start()
        assert rig.clock.is_simulated
        rig.clock.advance(0.01)  # type: ignore[attr-defined]
        assert drives[0].node.nmt_state is NmtState.PRE_OPERATIONAL and drives[0].node.node_id == 2
        assert drives[1].node.node_id is None
        assert drives[0].node.get(0x1018, 4) == 0x1002
        # a drive publishes no endpoint; the ready file lists it with its EDS (for `gatewaylab monitor`)
        listed = drives[0].ready_info()["canopen"]["can0"]["axis2"]
        assert (listed["node_id"], listed["serial"]) == (2, 0x1002)
        assert import_eds(Path(listed["eds"]).read_text(), 2).values[(0x1018, 4)] == 0x1002
    finally:
        for p in rig.participants:
            p.stop()


@pytest.mark.parametrize("cfg", [
    {"node_id": 2, "serial": 1},
    {"bus": "can9", "serial": 1},
    {"bus": "can0", "node_id": 0, "serial": 1},
    {"bus": "can0", "node_id": 128, "serial": 1},
    {"bus": "can0", "node_id": 2},
    {"bus": "can0", "serial": -1},
    {"bus": "can0", "serial": 1, "colour": "red"},
])
def test_bad_drive_sections(cfg: dict[str, object], tmp_path: Path) -> None:
    """Impossible [[drive]] sections are refused with a ConfigError naming the problem."""
    clock = SimulatedClock()
    rig = SimpleNamespace(clock=clock, buses={"can0": VirtualBus(clock, "can0")}, state_dir=tmp_path)
    with pytest.raises(ConfigError):
        create_drive(rig, cfg)
