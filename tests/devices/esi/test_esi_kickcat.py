"""ESI-built slaves brought to OP by KickCAT (an independent C++ master, PyPI ``kickcat``) through
``gatewaylab run`` on a veth pair: default timeouts, no retries, SCHED_FIFO 3 as KickCAT's README runs it
(tests/devices/esi/esi_kickcat_driver.py). The EL1859's inputs echo its outputs by rules alone."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from wire_kit import check_reruns, net_capable, rig_counters_env, rig_wire_stats, veth_namespace

from gatewaylab.rig.process import RigProcess

pytestmark = [pytest.mark.net, pytest.mark.slow]

DATA = Path(__file__).with_name("data")
DRIVER = Path(__file__).with_name("esi_kickcat_driver.py")
KITS = Path(__file__).resolve().parents[2] / "ethercat"      # kickcat_kit.py, for the driver
CYCLES = 2000
RIG = """
clock = "realtime"

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL1xxx-EL2xxx.xml"
type = "EL2008"

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL1xxx-EL2xxx.xml"
type = "EL1859"
[device.behaviour]
{echo}

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL1xxx-EL2xxx.xml"
type = "EL1008"

[[device]]
kind = "esi"
esi = "ethercat_io.xml"
name = "io-esi"

[ethercat]
interface = "{interface}"
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    reason = net_capable("kickcat")
    if reason is not None:
        pytest.skip(reason)
    work = tmp_path_factory.mktemp("esi-kickcat")
    subprocess.run([sys.executable, "-m", "gatewaylab", "esi", "ethercat_io", "--name", "io-esi",
                    "-o", str(work / "ethercat_io.xml")], check=True, capture_output=True, timeout=120)
    echo = "\n".join(f'"0x{0x6000 + 0x10 * i:04X}:01" = {{ echo = "0x{0x7000 + 0x10 * i:04X}:01" }}'
                     for i in range(8))
    with veth_namespace("gl-ekc-", "gek") as (ns, emu, mst):
        path = work / "rig.toml"
        path.write_text(RIG.format(data=DATA, echo=echo, interface=emu))
        with RigProcess(path, workdir=work, timeout=60) as rig:
            env = rig_counters_env(rig.info)    # the driver judges each rerun by the rig's wire counters
            env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(KITS), os.environ.get("PYTHONPATH")]))
            done = subprocess.run(["ip", "netns", "exec", ns, sys.executable, str(DRIVER), mst, str(CYCLES)],
                                  capture_output=True, text=True, timeout=600, check=False, env=env)
            assert rig.proc.poll() is None, rig.log_text()[-2000:]
            wire = rig_wire_stats(rig.info)
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    check_reruns(result["retries"], wire)
    yield result


def test_kickcat_brings_the_esi_slaves_to_op(run: dict[str, Any]) -> None:
    """KickCAT sizes each slave's image from the PDO assignment it reads (CoE, or SII for the terminals
    without a mailbox): bytes as the ESIs declare them."""
    assert run["count"] == 4
    assert run["sizes"][:3] == [[1, 0], [1, 1], [0, 1]]
    assert run["sizes"][3] == [5, 9]          # ethercat_io: outputs U8 + 2 x S16, inputs U8 + 2 x S16 + U32
    assert all("OPERATIONAL" in s or "OP" in s for s in run["op"]), run["op"]


def test_kickcat_cycles_and_sees_the_echo(run: dict[str, Any]) -> None:
    """No wrong working counter; lost cycles (no reply within KickCAT's 2 ms) counted, printed, up to 2 %.
    KickCAT reads the inputs (LRD) before it writes the outputs (LWR): the EL1859's inputs of a cycle echo the
    outputs of the cycle before (compared where that one was not lost)."""
    echo = run["echo"]
    bad = [(b, a) for a, b in itertools.pairwise(echo) if b[0] == a[0] + 1 and b[2] != a[1]]
    print(f"cycles {CYCLES}: lost {run['lost']}, wrong WKC {run['bad_wkc']}, echo mismatches {len(bad)}: {bad[:10]}; "
          f"scans run again after a lost frame: {run['retries']}")
    assert run["bad_wkc"] == 0
    assert run["lost"] <= CYCLES // 50
    assert len(echo) == CYCLES - run["lost"] and not bad
    assert len({row[2] for row in echo}) > 100
