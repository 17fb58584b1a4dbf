"""Distributed-clock faults as pysoem (SOEM) sees them over a veth pair: ``gatewaylab run`` with three devices on
10 m cables, the faults injected from another process with ``gatewaylab fault READY-FILE ...``, one master
session throughout (the rig is never restarted).

What SOEM must see (ET1100 data sheet I "Distributed Clocks", II 0x0928 / 0x092C; SOEM ethercatdc.c): ``config_dc``
measures the propagation delays the cables make (one device passed + 5 ns per metre per hop); with the FRMW of
0x0910 that ``send_processdata`` adds once DC is configured, the system time difference 0x092C of every slave
stays small -- also of a slave whose clock drifts by 100 ppm; a slave drifting by 2000 ppm, beyond the time
control loop's limit, shows a growing difference; a jump of 5 ms shows in 0x092C; after ``ec-clear`` and
SOEM's DC re-initialisation (``config_dc`` again) every difference is small again.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from wire_kit import JsonMaster, net_capable, run_fault, veth_namespace

from gatewaylab.cli.fault import send_request
from gatewaylab.ethercat.esc_dc_clock import CABLE_NS_PER_M, FORWARD_NS
from gatewaylab.rig.process import RigProcess

pytestmark = [pytest.mark.net, pytest.mark.slow]
DRIVER = Path(__file__).with_name("ethercat_dc_faults_driver.py")
RIG = """
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
interface = "{iface}"
cable_m = 10.0
"""
#: |0x092C| a converged slave may show (ns): the loop settles at a few ns; the real-time clock's steps and the
#: uneven cycle of a loaded VM leave a little more
SMALL_NS = 50


class Line(JsonMaster):
    """The rig (``gatewaylab run`` child) and the pysoem driver in the namespace of the master's end."""

    def __init__(self, rig: RigProcess, namespace: str, iface: str) -> None:
        super().__init__(namespace, DRIVER, iface)
        self.rig, self.namespace, self.iface = rig, namespace, iface

    def fault(self, *args: str) -> dict[str, Any]:
        """``gatewaylab fault READY-FILE --json ARGS`` as a user runs it; its answer."""
        return run_fault(self.rig.ready_file, *args)

    def board(self) -> list[dict[str, Any]]:
        faults: list[dict[str, Any]] = send_request(str(self.rig.ready_file), {"fault": "ethercat-states"})["faults"]
        return faults

    def watch(self, n: int) -> dict[str, Any]:
        """``n`` cycles with DC; wrong working counters fail, lost cycles and reads are tolerated up to 2 %."""
        r = self.do("watch", n=n)
        print(f"watch {n}: last {r['last']}, tail max {r['tail_max']}, lost {r['lost']} cycles / "
              f"{r['lost_reads']} reads; before it {r['idle_lost']} of {r['idle_cycles']} lost")
        if r["bad_wkc"] or r["idle_bad_wkc"]:
            r["states"] = send_request(str(self.rig.ready_file), {"fault": "ethercat-states"})
        assert r["bad_wkc"] == 0 and r["idle_bad_wkc"] == 0, json.dumps(r)
        assert r["lost"] <= 0.02 * n and r["lost_reads"] <= 0.02 * 3 * n, r
        assert r["idle_lost"] <= 0.02 * r["idle_cycles"] + 1, r
        return r


@pytest.fixture
def line(tmp_path: Path) -> Iterator[Line]:
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-dc-", "gldc") as (ns, emu, mst):
        path = tmp_path / "rig.toml"
        path.write_text(RIG.format(iface=emu))
        with RigProcess(path, workdir=tmp_path, timeout=60) as rig:
            ln = Line(rig, ns, mst)
            try:
                yield ln
            finally:
                ln.close()
            assert rig.proc.poll() is None, rig.log_text()[-2000:]


def test_soem_dc_drift_compensation_follows_fails_and_recovers(line: Line) -> None:
    start = line.do("init")
    hop = round(FORWARD_NS + 10.0 * CABLE_NS_PER_M)
    assert start["count"] == 3 and start["dc"] and start["op"] == 8
    assert start["delays"] == [0, hop, 2 * hop]               # SOEM's measurement = the model's cables
    quiet = line.watch(300)
    assert max(quiet["tail_max"]) <= SMALL_NS and all(v is not None and abs(v) <= 4 for v in quiet["speed"])

    drift = line.fault("ec-dc-drift", "io-b", "100")
    assert drift["fault"] == "ec-dc-drift" and drift["ppm"] == 100
    assert [(f["fault"], f["target"]) for f in line.board()] == [("ec-dc-drift", "io-b")]
    follow = line.watch(400)
    assert max(follow["tail_max"]) <= SMALL_NS                # the loop follows 100 ppm ...
    # ... by slowing io-b down: 100 of the loop's 500 ppm are (0x1000 - 0x7F) / 5 = 794 speed counter steps
    assert follow["speed"][1] is not None and -850 < follow["speed"][1] < -740, follow["speed"]

    line.fault("ec-dc-drift", "io-c", "-2000")
    lose = line.watch(200)
    assert lose["last"][2] is not None and lose["last"][2] < -50_000   # behind ...
    assert lose["tail_max"][2] == -lose["last"][2]                     # ... and more so each cycle
    assert lose["tail_max"][1] <= SMALL_NS                    # io-b still follows

    ended = line.fault("ec-clear")["ended"]
    assert sorted(e["target"] for e in ended) == ["io-b", "io-c"] and line.board() == []
    assert line.do("config_dc")["dc"]
    again = line.watch(400)
    assert max(again["tail_max"]) <= SMALL_NS

    jump = line.fault("ec-dc-jump", "io-a", "--", "-5000000")
    assert jump["ns"] == -5_000_000 and line.board() == []
    # io-a is the reference clock: its system time went back 5 ms, the others are ahead of it by that much, less
    # what their loops slewed since (at most 500 ns per ms: the master kept cycling while `gatewaylab fault` ran)
    jumped = line.watch(30)
    assert all(d is not None and 1_000_000 < d <= 5_000_000 for d in jumped["last"][1:]), jumped
    assert line.do("config_dc")["dc"]
    healed = line.watch(400)
    assert max(healed["tail_max"]) <= SMALL_NS
