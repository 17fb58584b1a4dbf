"""The board of active EtherCAT faults (gatewaylab/rig/faults_core.py; docs/faults.md "EtherCAT faults"):
a fault in force is listed by ``ethercat-states`` while it lasts, ends by its duration, by its count or on
``ec-clear`` -- each time undone once -- and the three faces (Python, control request, pytest plugin's
``RigHandle.fault``) reach the same method."""

from __future__ import annotations

from pathlib import Path

import pytest

from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.pytest_plugin import RigHandle
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[ethercat]
interface = "gl-none"
"""


@pytest.fixture
def rig(tmp_path: Path) -> Rig:
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    made = Rig.from_file(path)
    made.start()
    return made


def test_a_fault_with_a_duration_is_listed_until_it_ends_and_is_undone_once(rig: Rig) -> None:
    undone: list[str] = []
    with rig:
        with rig.clock.lock:
            entry = rig.faults.activate("ec-test", "io-a", {"left": 2}, lambda: undone.append("a"), seconds=0.5)
        listed = rig.faults.request({"fault": "ethercat-states"})["faults"]
        assert listed == [{"id": entry.ident, "fault": "ec-test", "target": "io-a", "left": 2,
                           "ends_at": pytest.approx(rig.clock.now() + 0.5)}]
        rig.clock.advance(0.4)      # type: ignore[attr-defined]
        assert len(rig.faults.board) == 1 and undone == []
        rig.clock.advance(0.2)      # type: ignore[attr-defined]
        assert rig.faults.request({"fault": "ethercat-states"})["faults"] == [] and undone == ["a"]
        with rig.clock.lock:
            rig.faults.finish(entry.ident)      # ended already: nothing undone twice
        assert undone == ["a"]


def test_ec_clear_ends_the_faults_of_one_device_or_all(rig: Rig) -> None:
    undone: list[str] = []
    with rig:
        with rig.clock.lock:
            for target in ("io-a", "io-b", "segment"):
                rig.faults.activate("ec-test", target, {}, lambda t=target: undone.append(t))  # type: ignore[misc]
        answer = rig.faults.request({"fault": "ec-clear", "device": "io-b"})
        assert [e["target"] for e in answer["ended"]] == ["io-b"] and undone == ["io-b"]
        answer = rig.faults.request({"fault": "ec-clear"})
        assert [e["target"] for e in answer["ended"]] == ["io-a", "segment"]
        assert undone == ["io-b", "io-a", "segment"] and len(rig.faults.board) == 0
        with pytest.raises(FaultRefused, match="no device 'nope'"):
            rig.faults.request({"fault": "ec-clear", "device": "nope"})


def test_the_pytest_plugin_handle_reaches_the_same_request(rig: Rig, tmp_path: Path) -> None:
    with rig:
        handle = RigHandle(tmp_path, {}, rig=rig)
        assert handle.fault("ec-clear") == {"fault": "ec-clear", "device": None, "ended": []}
        assert set(handle.fault("ethercat-states")["devices"]) == {"io-a", "io-b"}
