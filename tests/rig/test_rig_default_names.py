"""Default device names are unique in a rig (issue 21 defect 4; docs/rig.md "Names").

CiA 301 node-IDs are unique per network, not per rig: drive 2 on can0 and drive 2 on can1 is a
legal rig, and it must start without hand-written names. A default that no other section has
stays as it is (``drive2``, what docs and users already type); defaults that meet carry their bus
(``drive2@can0``, ``drive2@can1``), else a number in rig-file order. The ready file and
`gatewaylab fault` take those names as they are.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import can
import pytest

from gatewaylab.canopen.cia402 import PdsState
from gatewaylab.cli.monitor import _dictionaries
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.process import RigProcess
from gatewaylab.rig.runtime import Rig

WAIT = 20.0

TWO_BUSES_TOML = """\
[[bus]]
name = "can0"
[[bus]]
name = "can1"
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
[[drive]]
bus = "can1"
node_id = 2
serial = 0x1002
[[drive]]
bus = "can1"
node_id = 3
serial = 0x1003
"""

TWO_BUSES: dict[str, Any] = {
    "clock": "simulated", "bus": [{"name": "can0"}, {"name": "can1"}],
    "drive": [{"bus": "can0", "node_id": 2, "serial": 0x1002},
              {"bus": "can1", "node_id": 2, "serial": 0x1002},
              {"bus": "can1", "node_id": 3, "serial": 0x1003}]}


def _names(data: dict[str, Any]) -> list[str | None]:
    from gatewaylab.rig import kinds
    return [s.name for s in kinds.plan(parse_rig(data))]


def _drive(rig: Rig, name: str) -> Drive:
    p = next(p for p in rig.participants if p.name == name)
    assert isinstance(p, Drive)
    return p


def test_same_node_id_on_two_buses_starts_in_process_with_distinct_names() -> None:
    """CiA 301: node-IDs are unique per network. Both drives 2 are built, each under its own name,
    each with its own stored-parameter and EDS file; a fault by name reaches that drive only."""
    with Rig(parse_rig(TWO_BUSES)) as rig:
        rig.start()
        rig.clock.advance(0.1)
        assert [p.name for p in rig.participants] == ["drive2@can0", "drive2@can1", "drive3"]
        d0, d1 = _drive(rig, "drive2@can0"), _drive(rig, "drive2@can1")
        assert d0.node.bus is rig.buses["can0"] and d1.node.bus is rig.buses["can1"]
        canopen = rig.ready_info()["canopen"]
        assert set(canopen["can0"]) == {"drive2@can0"} and set(canopen["can1"]) == {"drive2@can1", "drive3"}
        assert Path(canopen["can0"]["drive2@can0"]["eds"]) != Path(canopen["can1"]["drive2@can1"]["eds"])
        answer = rig.faults.drive_fault("drive2@can1")
        rig.clock.advance(0.1)
        assert answer["device"] == "drive2@can1"
        assert d1.state is PdsState.FAULT and d0.state is not PdsState.FAULT


def test_unique_defaults_stay_as_they_were() -> None:
    """Backward compatible: a rig whose node-IDs are unique keeps ``drive2`` (docs, users' scripts)."""
    assert _names({"bus": [{"name": "can0"}, {"name": "can1"}],
                   "drive": [{"bus": "can0", "node_id": 2, "serial": 1},
                             {"bus": "can1", "node_id": 3, "serial": 2},
                             {"bus": "can1", "serial": 0x1004}]}) == ["drive2", "drive3", "drive-1004"]


@pytest.mark.parametrize("data, expected", [
    # the default meets an explicit name: only the default one changes
    ({"bus": [{"name": "can0"}], "drive": [{"bus": "can0", "node_id": 3, "serial": 1, "name": "drive2"},
                                           {"bus": "can0", "node_id": 2, "serial": 2}]},
     ["drive2", "drive2@can0"]),
    # two IDXs (each with a drive inside) on two buses
    ({"bus": [{"name": "can0"}, {"name": "can1"}],
      "device": [{"kind": "maxon_idx", "bus": "can0", "node_id": 1, "usb": {"pty": False}},
                 {"kind": "maxon_idx", "bus": "can1", "node_id": 1, "usb": {"pty": False}}]},
     ["idx@can0", "idx@can1"]),
    # the same bus: the bus does not tell them apart, a number in file order does
    ({"bus": [{"name": "can0"}],
      "device": [{"kind": "maxon_idx", "node_id": 1, "serial": 1, "usb": {"pty": False}},
                 {"kind": "maxon_idx", "node_id": 4, "serial": 4, "usb": {"pty": False}}]},
     ["idx1", "idx2"]),
    # EtherCAT kinds have no bus; a number that is taken by an explicit name is skipped
    ({"device": [{"kind": "ethercat_io"}, {"kind": "ethercat_io", "name": "ethercat_io1"}, {"kind": "ethercat_io"}]},
     ["ethercat_io2", "ethercat_io1", "ethercat_io3"]),
    # unconfigured drives with one serial on two buses
    ({"bus": [{"name": "can0"}, {"name": "can1"}],
      "drive": [{"bus": "can0", "serial": 0x1004}, {"bus": "can1", "serial": 0x1004}]},
     ["drive-1004@can0", "drive-1004@can1"]),
])
def test_default_names_that_meet_become_unique(data: dict[str, Any], expected: list[str]) -> None:
    """Issue 21 defect 4: 'Default names must be unique in a rig (e.g. include the bus)'."""
    assert _names(data) == expected


def test_an_explicit_name_equal_to_a_made_default_is_still_refused() -> None:
    """Names given in the file are never changed; two devices with one name stay a one-line error."""
    with pytest.raises(ConfigError, match=r"\[\[drive\]\] #3: name = 'drive2@can1' \(the default name\) is already "
                                          r"used by \[\[drive\]\] #1 \(drive2@can1\)"):
        parse_rig({"bus": [{"name": "can0"}, {"name": "can1"}],
                   "drive": [{"bus": "can0", "node_id": 5, "serial": 5, "name": "drive2@can1"},
                             {"bus": "can0", "node_id": 2, "serial": 1},
                             {"bus": "can1", "node_id": 2, "serial": 2}]})


def _emcy(bus: can.BusABC, node_id: int, code: int) -> list[int]:
    """Wait for EMCY ``code`` of ``node_id`` (CiA 301 7.2.7: COB-ID 0x80 + node-ID, code LE in bytes 0-1);
    returns every EMCY code the node sent up to it."""
    seen: list[int] = []
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        msg = bus.recv(0.5)
        if msg is not None and msg.arbitration_id == 0x80 + node_id and len(msg.data) == 8:
            seen.append(int.from_bytes(msg.data[:2], "little"))
            if seen[-1] == code:
                return seen
    raise AssertionError(f"no EMCY 0x{code:04X} from node {node_id} within {WAIT} s (saw {seen})")


def _fault_cli(rig: RigProcess, *args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "gatewaylab", "fault", str(rig.ready_file), *args],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_gatewaylab_run_lists_both_and_gatewaylab_fault_takes_each_name(tmp_path: Path) -> None:
    """The user's path: `gatewaylab run` starts the rig, its ready file lists drive 2 of each bus
    under its own name, and `gatewaylab fault READY drive-fault NAME` reaches that drive only:
    EMCY 0x8611 (following error) on can1, then 0x2310 (over-current) on can0 and never 0x8611
    there (docs/faults.md; CiA 402 / CiA 301 EMCY)."""
    rig_file = tmp_path / "two-buses.toml"
    rig_file.write_text(TWO_BUSES_TOML)
    with RigProcess(rig_file, workdir=tmp_path) as rig:
        canopen = rig.info["canopen"]
        assert set(canopen["can0"]) == {"drive2@can0"} and set(canopen["can1"]) == {"drive2@can1", "drive3"}
        assert canopen["can0"]["drive2@can0"]["node_id"] == canopen["can1"]["drive2@can1"]["node_id"] == 2
        # `gatewaylab monitor READY --bus can1` decodes the PDOs of can1's drives with their EDS files
        monitor_args = argparse.Namespace(target=str(rig.ready_file), bus="can1", replay=False, eds=None)
        assert set(_dictionaries(monitor_args)) == {2, 3}
        with can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as bus0, \
                can.Bus(interface="gatewaylab", channel=rig.endpoint("can1")) as bus1:
            out = _fault_cli(rig, "drive-fault", "drive2@can1", "following-error")
            assert "device=drive2@can1" in out
            _emcy(bus1, 2, 0x8611)
            out = _fault_cli(rig, "drive-fault", "drive2@can0", "over-current")
            assert "device=drive2@can0" in out
            assert 0x8611 not in _emcy(bus0, 2, 0x2310)
            out = _fault_cli(rig, "power-cycle", "drive2@can1", "--off", "0")
            assert "device=drive2@can1" in out
