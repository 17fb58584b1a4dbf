"""Scenarios (issue 34 item 9; docs/faults.md "Scenarios"): ``[[scenario]]`` steps checked when they load
(one line naming the step, the key and the problem; `gatewaylab run` exits 2), fired at a time or at a
milestone of the segment (an AL state reached, the N-th process-data cycle, an SDO request to an index),
exactly the same way twice on a simulated clock; the pytest plugin's ``gatewaylab_scenario`` marker."""

from __future__ import annotations

import struct
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.cli.monitor import EthercatWatcher
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.milestones import sdo_index
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig
from gatewaylab.rig.scenario import load_scenario, parse_scenario

LINE = """
clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[[device]]
kind = "ethercat_io"
name = "io-c"
serial = 8
[ethercat]
interface = "gl-none"
"""

STEPS = """
[[scenario]]
after_state = {device = "io-c", state = "OP"}
delay = 0.005
fault = "ethercat-unplug"
device = "io-b"
end_after = 0.004
[[scenario]]
after_cycles = 20
fault = "ethercat-unplug"
device = "io-c"
end_after = 0.003
[[scenario]]
after_sdo = {device = "io-a", index = 0x1018}
fault = "ethercat-unplug"
device = "io-c"
[[scenario]]
at = 0.1
fault = "ethercat-replug"
device = "io-c"
"""


def _error(text: str) -> str:
    with pytest.raises(ConfigError) as info:
        parse_scenario(tomllib.loads(text)["scenario"], "s.toml")
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(("step", "expected"), [
    ('at = 1\nfault = "ec-bogus"', "s.toml [[scenario]] #1: fault: unknown fault 'ec-bogus'"),
    ('at = 1\nfault = "ethercat-unplug"\ndevice = 3', "#1: arguments: ethercat-unplug: device must be string"),
    ('at = 1\nfault = "ethercat-unplug"\ndevice = "x"\ncolour = 1', "unknown argument 'colour'"),
    ('at = 1\nfault = "ethercat-unplug"', "#1: arguments: ethercat-unplug: missing device"),
    ('fault = "ec-clear"', "#1: needs a trigger: one of at, after_state, after_cycles, after_sdo"),
    ('at = 1\nafter_cycles = 3\nfault = "ec-clear"', "#1: has 2 triggers (at, after_cycles): one per step"),
    ('at = -1\nfault = "ec-clear"', "#1: at must be a number of seconds >= 0, got -1"),
    ('after_cycles = 0\nfault = "ec-clear"', "#1: after_cycles must be a whole number >= 1, got 0"),
    ('after_state = {device = "io-a", state = "RUN"}\nfault = "ec-clear"', "#1: after_state.state must be one of"),
    ('after_state = {device = "io-a"}\nfault = "ec-clear"', "#1: after_state needs state"),
    ('after_sdo = {device = "io-a", index = 0x10000}\nfault = "ec-clear"', "after_sdo.index must be an object index"),
    ('after_sdo = {device = "io-a", idx = 1}\nfault = "ec-clear"', "unknown after_sdo keys ['idx']"),
    ('at = 1\nfault = "drop"\nbus = "can0"\ncan_id = 1\nend_after = 1', "#1: end_after: drop is not a fault"),
    ('at = 1\nfault = "ethercat-states"', "is a status request, not a fault"),
    ("at = 1", "#1: needs fault = \"VERB\""),
])
def test_a_bad_step_is_one_line_naming_step_and_key(step: str, expected: str) -> None:
    """Every step is checked when it loads, against the control endpoint's request table (docs/faults.md
    "Control protocol": verbs and typed arguments): one ConfigError line naming the file, the step, the key."""
    message = _error('[[scenario]]\nat = 0\nfault = "ec-clear"\n[[scenario]]\n' + step)
    assert "s.toml [[scenario]] #2" in message or "#2" in message
    assert expected.replace("#1", "#2") in message, message


_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-2, 0x10001), st.floats(allow_nan=True),
                    st.sampled_from(["OP", "BOOT", "io-a", "ec-clear", "ethercat-unplug", "x"]),
                    st.dictionaries(st.sampled_from(["device", "state", "index", "x"]),
                                    st.one_of(st.integers(-1, 0x10000), st.sampled_from(["io-a", "OP", "y"]))))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.dictionaries(st.sampled_from(["at", "after_state", "after_cycles", "after_sdo", "delay",
                                                 "end_after", "fault", "device", "bus", "count", "zz"]),
                                _VALUES), max_size=3))
def test_any_steps_load_or_give_one_config_error_line(raw: list[dict[str, Any]]) -> None:
    """Whatever the tables hold, loading gives steps or one ConfigError line naming the step, never
    another exception (DEVELOPERS.md Standards: every parser)."""
    try:
        steps = parse_scenario(raw, "s.toml")
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("s.toml [[scenario]] #")
    else:
        assert [s.number for s in steps] == list(range(1, len(raw) + 1))


def test_a_scenario_file_holds_scenario_steps_only(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('clock = "simulated"\n' + STEPS)
    with pytest.raises(ConfigError, match=r"unknown top-level keys \['clock'\]"):
        load_scenario(path)
    path.write_text(STEPS)
    steps = load_scenario(path)
    assert [s.trigger for s in steps] == ["after_state", "after_cycles", "after_sdo", "at"]
    assert steps[2].value == 0x1018 and steps[0].request == {"fault": "ethercat-unplug", "device": "io-b"}
    assert tomllib.loads(STEPS)["scenario"] == [s.as_json() for s in steps]


def test_a_trigger_naming_no_ethercat_device_is_refused_when_the_rig_is_built() -> None:
    with pytest.raises(ConfigError, match=r"#1: after_state.device = 'io-x' is not an EtherCAT device"):
        Rig(parse_rig(tomllib.loads(LINE + '[[scenario]]\nafter_state = {device = "io-x", state = "OP"}\n'
                                          'fault = "ec-clear"\n'), "r.toml"))


def test_sdo_index_reads_initiate_requests_only() -> None:
    """ETG.1000.6 5.6.2.1/5.6.2.4: mailbox header (type 3 CoE), CoE header (service 2 SDO request), command
    (ccs 1 download / 2 upload), index, subindex; a segment request (ccs 0) carries no index."""
    upload = struct.pack("<HHBB", 10, 0, 0, 0x03) + struct.pack("<H", 0x2000) + bytes([0x40]) + \
        struct.pack("<HB", 0x1C12, 0) + bytes(4)
    assert sdo_index(upload) == 0x1C12
    assert sdo_index(upload[:5] + bytes([0x04]) + upload[6:]) is None            # FoE, not CoE
    assert sdo_index(upload[:8] + bytes([0x00]) + upload[9:]) is None            # a download segment
    assert sdo_index(upload[:6] + struct.pack("<H", 0x3000) + upload[8:]) is None  # an SDO response


def _run(tmp_path: Path) -> list[tuple[Any, ...]]:
    """The in-process master brings the line to OP, reads 0x1018 of io-a at cycle 30, runs 40 cycles 1 ms
    apart; what the scenario fired, when, and what it answered."""
    path = tmp_path / "rig.toml"
    path.write_text(LINE + STEPS)
    with Rig.from_file(path) as rig:
        rig.start()
        segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
        master = Master(rig.clock, segment)
        master.bring_up()
        wkcs = []
        for i in range(40):
            rig.clock.advance(0.001)
            wkcs.append(master.exchange_process_data())
            if i == 30:
                master.sdo_upload(0, 0x1018, 1)
        rig.clock.advance(0.2)
        scenario = rig.faults.ethercat_states()["scenario"]
        assert segment.observer is None          # every milestone met: the frame path is back to one check
    assert scenario["steps"] == 4
    fired = scenario["fired"]
    assert [r["step"] for r in fired] == [1, 2, 3, 4]
    assert fired[0]["answer"]["unreachable"] == ["io-b", "io-c"] and fired[0]["end"] == "ended by ethercat-replug"
    assert fired[0]["ended_at"] == pytest.approx(fired[0]["at"] + 0.004)
    assert fired[2]["answer"]["unreachable"] == ["io-c"]
    assert fired[3]["answer"]["al_status"] == AlState.INIT
    assert wkcs[0] == master.expected_wkc and wkcs[5] < master.expected_wkc
    return [(r["step"], r["at"], r["trigger"], r["fault"], r.get("ended_at")) for r in fired] + [tuple(wkcs)]


def test_the_monitor_prints_each_step_once_as_it_fires_and_ends(tmp_path: Path) -> None:
    """`gatewaylab monitor` reads ``ethercat-states`` twice a second: a step is one ``ethercat`` line when it
    fired and one when ``end_after`` ended it, never repeated by a later answer."""
    path = tmp_path / "rig.toml"
    path.write_text(LINE + STEPS)
    watcher = EthercatWatcher("unix:/nonexistent")
    with Rig.from_file(path) as rig:
        rig.start()
        segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
        Master(rig.clock, segment).bring_up()
        rig.clock.advance(0.006)
        first = [e.text for e in watcher.changes(rig.faults.ethercat_states(), 1.0) if "scenario" in e.text]
        rig.clock.advance(0.01)
        again = [e.text for e in watcher.changes(rig.faults.ethercat_states(), 2.0) if "scenario" in e.text]
    assert first == ["EtherCAT scenario step 1/4 (after io-c reached OP + 0.005 s) at 0.005 s: ethercat-unplug fired"]
    assert again == ["EtherCAT scenario step 1/4 at 0.009 s: ethercat-unplug ended by ethercat-replug"]


def test_the_same_scenario_fires_the_same_steps_at_the_same_times(tmp_path: Path) -> None:
    """On a simulated clock a scenario is exact: two runs of the same master give the same steps at the
    same times and the same working counters (issue 34 item 9: a CI job reproduces the sequence)."""
    (tmp_path / "1").mkdir()
    (tmp_path / "2").mkdir()
    first = _run(tmp_path / "1")
    assert first == _run(tmp_path / "2")
    # io-c reached OP at 0 s (bring-up) + delay 0.005; ended 0.004 later; the SDO was read at 0.031 s
    assert first[0][1:] == (0.005, "after io-c reached OP + 0.005 s", "ethercat-unplug", 0.009)
    assert first[2][1:] == (0.031, "after SDO to io-a 0x1018", "ethercat-unplug", None)


def test_gatewaylab_run_refuses_a_bad_scenario_file_with_exit_2(tmp_path: Path) -> None:
    """`gatewaylab run --scenario FILE` (relative to the working folder) checks the file before the rig starts."""
    (tmp_path / "rig.toml").write_text(LINE.replace('clock = "simulated"', ""))
    (tmp_path / "bad.toml").write_text('[[scenario]]\nafter_cycles = 5\nfault = "ec-nosuch"\n')
    proc = subprocess.run([sys.executable, "-m", "gatewaylab", "run", "rig.toml", "--scenario", "bad.toml"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "bad.toml [[scenario]] #1: fault: unknown fault 'ec-nosuch'" in lines[0], lines


@pytest.mark.gatewaylab_scenario(steps=[{"after_cycles": 3, "fault": "ethercat-unplug", "device": "io-b"}])
def test_the_marker_arms_the_rigs_of_the_test(gatewaylab_rig: Any) -> None:
    """``@pytest.mark.gatewaylab_scenario(steps=[...])``: the rig gatewaylab_rig starts fires the steps; the
    third process-data cycle unplugs io-b, the fourth sees the lower working counter."""
    handle = gatewaylab_rig(tomllib.loads(LINE), clock="simulated")
    segment = next(p for p in handle.rig.participants if p.name == "ethercat").segment
    master = Master(handle.clock, segment)
    master.bring_up()
    wkcs = [master.exchange_process_data() for _ in range(4)]
    fired = handle.fault("ethercat-states")["scenario"]["fired"]
    assert [(r["step"], r["fault"], r["answer"]["device"]) for r in fired] == [(1, "ethercat-unplug", "io-b")]
    assert wkcs[-1] < wkcs[0] == master.expected_wkc


@pytest.mark.gatewaylab_scenario("scenario_steps.toml")
def test_the_marker_reads_a_file_next_to_the_test(gatewaylab_rig: Any) -> None:
    """``@pytest.mark.gatewaylab_scenario("FILE")``: relative to the test file's folder; ``scenario=`` of the
    factory overrides it."""
    handle = gatewaylab_rig(tomllib.loads(LINE), clock="simulated")
    assert handle.rig.scenario is not None and len(handle.rig.scenario.steps) == 2
    other = gatewaylab_rig(tomllib.loads(LINE), clock="simulated", scenario=[{"at": 1, "fault": "ec-clear"}])
    assert len(other.rig.scenario.steps) == 1
    handle.clock.advance(0.5)
    fired = handle.rig.faults.ethercat_states()["scenario"]["fired"]
    assert [(r["step"], r["at"], r["fault"]) for r in fired] == [(1, 0.25, "ethercat-unplug")]


CAN_RIG = {"bus": [{"name": "can0"}], "drive": [{"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"}]}


@pytest.mark.gatewaylab_scenario(steps=[{"at": 0.0, "fault": "can-unplug", "device": "axis2", "end_after": 60.0}])
def test_the_marker_reaches_a_rig_in_a_child_process(gatewaylab_rig: Any) -> None:
    """The default rig of gatewaylab_rig is `gatewaylab run` in a child: the marker's steps go to it as
    ``--scenario`` (a file in the rig's work folder); an ``at`` step needs no EtherCAT segment. The child
    unplugs axis2's CAN controller at once, and says so in ``ethercat-states``."""
    handle = gatewaylab_rig(CAN_RIG)
    assert handle.process is not None
    fired: list[dict[str, Any]] = []
    deadline = time.monotonic() + 30
    while not fired and time.monotonic() < deadline:     # the child's loop runs the step after the ready file
        fired = handle.fault("ethercat-states")["scenario"]["fired"]
        if not fired:
            time.sleep(0.05)
    assert [(r["step"], r["fault"], r["answer"]["device"]) for r in fired] == [(1, "can-unplug", "axis2")]
    assert handle.fault("can-states")["buses"]["can0"]["axis2"]["connected"] is False
