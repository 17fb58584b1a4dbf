"""A scenario through ``gatewaylab run --scenario FILE`` against pysoem over a veth pair (issue 34 item 9;
docs/faults.md "Scenarios"): the rig unplugs io2 0.3 s after io1 reached OP and plugs it back in 0.6 s
later; a time step and a cycle step fire too. ETG.1000.4 working counter: while io2 is out, io2 and io3
(behind it) add nothing to the LRW; plugged back in, io2 powers on in INIT (ETG.1000.6) and SOEM
simple_test's recovery (recover the lost slave, reconfigure it, SAFEOP -> OP) brings the counter back
without restarting the rig. The rig's log and ``ethercat-states`` say which step fired when.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.common.ask import ask, endpoint_address
from gatewaylab.common.endpoint import EndpointKind, parse_endpoint
from gatewaylab.rig.process import RigProcess

pytestmark = [pytest.mark.net, pytest.mark.slow]
DRIVER = Path(__file__).with_name("ethercat_scenario_soem_driver.py")
RIG = """
[[device]]
kind = "ethercat_io"
name = "io1"
serial = 101
[[device]]
kind = "ethercat_io"
name = "io2"
serial = 102
[[device]]
kind = "ethercat_io"
name = "io3"
serial = 103
[ethercat]
interface = "{interface}"
"""
SCENARIO = """
[[scenario]]
after_state = {device = "io1", state = "OP"}
delay = 0.3
fault = "ethercat-unplug"
device = "io2"
end_after = 0.6

[[scenario]]
after_cycles = 20
fault = "ec-clear"

[[scenario]]
at = 0.0
fault = "ec-clear"
device = "io3"
"""
#: the per-slave share of the LRW working counter of an ethercat_io (outputs written 2, inputs read 1)
PER_SLAVE = 3


@pytest.fixture(scope="module")
def scenario_run(veth_ns: Any, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    workdir = tmp_path_factory.mktemp("scenario")
    (workdir / "rig.toml").write_text(RIG.format(interface=veth_ns.emulator_iface))
    (workdir / "steps.toml").write_text(SCENARIO)
    with RigProcess(workdir / "rig.toml", "--scenario", str(workdir / "steps.toml"), workdir=workdir,
                    timeout=60) as rig:
        proc = subprocess.run(["ip", "netns", "exec", veth_ns.namespace, sys.executable, str(DRIVER),
                               veth_ns.master_iface, "20"], capture_output=True, text=True, timeout=180,
                              check=False)
        endpoint = parse_endpoint(str(rig.info["control"]), bare_path=EndpointKind.UNIX)
        states = json.loads(ask(endpoint_address(endpoint), {"fault": "ethercat-states"}, 10.0) or b"{}")
        assert rig.proc.poll() is None, rig.log_text()[-2000:]
        log = rig.log_text()
    assert proc.returncode == 0, proc.stderr[-2000:]
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    result["states"] = states
    result["log"] = log
    return result


def test_the_master_sees_the_unplug_and_recovers(scenario_run: dict[str, Any]) -> None:
    """Full counter in OP, then io1's share only while io2 is out, then full again after simple_test's
    recovery; a reply with any other counter than those of the line's states fails (no wrong answer), lost
    cycles (no reply) are counted, at most 2 %."""
    r = scenario_run
    full = r["expected_wkc"]
    assert (r["count"], r["op"], full) == (3, 8, 3 * PER_SLAVE)
    wkcs = r["wkcs"]
    lost = sum(1 for w in wkcs if w < 0)
    print(f"{len(wkcs)} cycles, {lost} lost, recovery: {r['recovery']}")
    assert lost <= 0.02 * len(wkcs)
    replies = [w for w in wkcs if w >= 0]
    assert replies[0] == full
    assert PER_SLAVE in replies                                    # io2 (and io3 behind it) out
    assert set(replies) <= {full, PER_SLAVE, 2 * PER_SLAVE}        # io3 alone in OP after the replug: 6
    assert replies[-1] == full and any(line.endswith("recovered") for line in r["recovery"])


def test_the_rig_says_which_step_fired_when(scenario_run: dict[str, Any]) -> None:
    """``ethercat-states`` lists the steps fired (step, time since the rig started, trigger, fault, answer);
    the rig's log has one line per step as it fired."""
    fired = {rec["step"]: rec for rec in scenario_run["states"]["scenario"]["fired"]}
    assert scenario_run["states"]["scenario"]["steps"] == 3 and set(fired) == {1, 2, 3}
    assert fired[3]["at"] >= 0.0 and fired[3]["answer"]["device"] == "io3"
    assert fired[1]["answer"]["unreachable"] == ["io2", "io3"] and fired[1]["end"] == "ended by ethercat-replug"
    assert fired[1]["ended_at"] >= fired[1]["at"] + 0.6         # a clock's timer never fires early
    assert fired[2]["trigger"] == "after cycle 20"
    log = scenario_run["log"]
    assert "scenario step 1 (after io1 reached OP + 0.3 s) at " in log
    assert not [line for line in log.splitlines() if line.startswith(("ERROR", "CRITICAL", "Traceback"))]
    assert "scenario step 2 (after cycle 20) at " in log and "scenario step 3 (at 0.0 s) at " in log
