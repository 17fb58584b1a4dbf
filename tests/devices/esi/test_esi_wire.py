"""ESI-built slaves on the user's path: ``gatewaylab run`` with the ``[ethercat]`` segment on one end of a
veth pair, pysoem (SOEM) as the master in a network namespace on the other.

The segment: ``ethercat_io`` and ``ethercat_drive`` each next to the slave built from its own exported ESI
(``gatewaylab esi KIND -o FILE``, then ``kind = "esi"``), and the test terminals EL2008, EL1008, EL1859
(inputs echo the outputs: rules, no code) and EL3102 (channel 1 draws a sine). SOEM must find the same SII
bytes, PDO map and SDO information dictionary in each original and its copy, bring all eight to OP and cycle
with the expected working counter.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from wire_kit import lost_allowed, net_capable, veth_namespace

from gatewaylab.rig.process import RigProcess

pytestmark = [pytest.mark.net, pytest.mark.slow]

DATA = Path(__file__).with_name("data")
DRIVER = Path(__file__).with_name("esi_soem_driver.py")
CYCLES = 600
RIG = """
clock = "realtime"

[[device]]
kind = "ethercat_io"
name = "io-orig"              # its SII device name; the ESI is exported with --name io-orig

[[device]]
kind = "esi"
esi = "ethercat_io.xml"
name = "io-esi"

[[device]]
kind = "ethercat_drive"
name = "axis-orig"

[[device]]
kind = "esi"
esi = "ethercat_drive.xml"
name = "axis-esi"

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL1xxx-EL2xxx.xml"
type = "EL2008"

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL1xxx-EL2xxx.xml"
type = "EL1008"

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL1xxx-EL2xxx.xml"
type = "EL1859"
[device.behaviour]
{echo}

[[device]]
kind = "esi"
esi = "{data}/GL-test-EL3102.xml"
type = "EL3102"
[device.behaviour]
"0x6000:11" = {{ sine = {{ amplitude = 10000, period = 0.2 }} }}

[ethercat]
interface = "{interface}"
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    work = tmp_path_factory.mktemp("esi-wire")
    for kind, name in (("ethercat_io", "io-orig"), ("ethercat_drive", "axis-orig")):
        subprocess.run([sys.executable, "-m", "gatewaylab", "esi", kind, "--name", name,
                        "-o", str(work / f"{kind}.xml")], check=True, capture_output=True, timeout=120)
    echo = "\n".join(f'"0x{0x6000 + 0x10 * i:04X}:01" = {{ echo = "0x{0x7000 + 0x10 * i:04X}:01" }}'
                     for i in range(8))
    with veth_namespace("gl-esi-", "gle") as (ns, emu, mst):
        path = work / "rig.toml"
        path.write_text(RIG.format(data=DATA, echo=echo, interface=emu))
        with RigProcess(path, workdir=work, timeout=60) as rig:
            done = subprocess.run(["ip", "netns", "exec", ns, sys.executable, str(DRIVER), mst, str(CYCLES)],
                                  capture_output=True, text=True, timeout=600, check=False)
            assert rig.proc.poll() is None, rig.log_text()[-2000:]
            log = rig.log_text()
            ready = rig.info
        assert done.returncode == 0, done.stderr[-3000:]
        result = json.loads(done.stdout.strip().splitlines()[-1])
        result["log"] = log
        result["ready"] = ready
        yield result


def test_soem_finds_eight_slaves_with_their_identities(run: dict[str, Any]) -> None:
    """SOEM's config_init reads the identity from SII words 0x08..0x0F and the name from the General
    category (ETG.2010): the copies carry the originals', the terminals the ESI's."""
    assert run["count"] == 8
    s = run["slaves"]
    assert [(x["man"], x["id"], x["rev"]) for x in s[4:]] == [
        (2, 0x07D83052, 0x00100000), (2, 0x03F03052, 0x00100000), (2, 0x07433052, 0x00100000),
        (2, 0x0C1E3052, 0x00140000)]
    for a, b in ((0, 1), (2, 3)):
        assert (s[a]["name"], s[a]["man"], s[a]["id"], s[a]["rev"]) == (s[b]["name"], s[b]["man"], s[b]["id"],
                                                                         s[b]["rev"])


@pytest.mark.parametrize("pair", [(0, 1), (2, 3)], ids=["ethercat_io", "ethercat_drive"])
def test_soem_cannot_tell_the_esi_copy_from_the_original(run: dict[str, Any], pair: tuple[int, int]) -> None:
    """The same SII bytes, the same PDO map (slaveinfo -map over CoE) and the same dictionary (SDO
    information: object list, object and entry descriptions, ETG.1000.6)."""
    a, b = (run["slaves"][i] for i in pair)
    print(f"SDO information exchanges SOEM asked again after its 700 ms timeout: {run['sdo_info_retries']}")
    assert a["sii"] == b["sii"]
    assert a["pdo_map"] == b["pdo_map"] and a["pdo_map"]
    assert a["od"] == b["od"] and len(a["od"]) > 10


def test_all_reach_op_and_cycle_with_the_expected_working_counter(run: dict[str, Any]) -> None:
    """SOEM's expected working counter: 2 per slave with outputs (LRW written and read) + 1 per slave with
    inputs only, or the sums per FMMU it computes; every cycle returns it."""
    assert run["safeop"] == 4 and run["op"] == 8
    print("lost frames (no reply within 2 ms):", run["lost"])
    assert run["bad_wkc"] == 0 and run["lost"] <= lost_allowed(CYCLES)
    assert run["sizes"][4:] == [[1, 0], [0, 1], [1, 1], [0, 8]]


def test_el1859_echoes_its_outputs_without_code(run: dict[str, Any]) -> None:
    """The rules run on the outputs SM event, inside the frame: the inputs of the same LRW carry the echo."""
    echo = run["echo"]
    bad = [(i, row) for i, row in enumerate(echo) if row[0] != row[1]]
    print(f"wkc expected {run['expected_wkc']}; echo mismatches {len(bad)}: {bad[:20]}")
    assert not bad


def test_el3102_sine_changes_over_cycles(run: dict[str, Any]) -> None:
    """Channel 1's value follows the sine rule (amplitude 10000, 0.2 s): the master sees it move across the
    whole range in 600 cycles of at least 1 ms."""
    values = run["values"][10:]
    assert max(values) > 9000 and min(values) < -9000 and max(abs(v) for v in values) <= 10000
    assert len(set(values)) > 100


def test_the_ready_file_says_where_each_slave_came_from(run: dict[str, Any]) -> None:
    """The ready file lists each ESI-built slave with its file and device type; nothing runs differently from
    the file, so the log has no note (an EL2008's outputs SyncManager stays on 0x0F00, where its ESI puts it)."""
    esi = run["ready"]["esi"]
    assert esi["io-esi"]["file"].endswith("ethercat_io.xml") and esi["EL3102"]["type"] == "EL3102"
    assert esi["EL1859"]["file"].endswith("GL-test-EL1xxx-EL2xxx.xml")
    assert not any("0x0F00" in line for line in run["log"].splitlines())


def test_digital_outputs_run_on_the_escs_output_register(run: dict[str, Any]) -> None:
    """ESI ``<Sm StartAddress="#x0f00" ControlByte="#x44">Outputs</Sm>`` (EL2008, EL1859): SOEM's config_map
    programs SM0 from the SII's SyncManager category at 0x0F00 (1 byte, control 0x44: buffered, ECAT writes,
    watchdog trigger; enabled) and its FMMU writes the outputs there: the master reads its last EL2008 outputs
    back from the Digital I/O Output Data register (ET1100 data sheet II, 0x0F00 ECAT r/w); the EL1859's echo
    (test above) shows the device takes its outputs from there."""
    d = run["digital_out"]
    for key in ("el2008_sm0", "el1859_sm0"):
        sm0 = bytes.fromhex(d[key])
        assert (sm0[0:2], sm0[2:4], sm0[4], sm0[6] & 1) == (b"\x00\x0f", b"\x01\x00", 0x44, 1), key
    assert d["el2008_0f00"] == d["el2008_out"]
