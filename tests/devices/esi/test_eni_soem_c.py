"""The ENI segment against SOEM's own C ``simple_test`` (built from the pysoem sdist at test time,
tests/ethercat/soem_samples.py), run from the test's network namespace against ``gatewaylab run``.

The segment is the test ENI's (data/GL-test-line.eni.xml, 12 slaves: ESI-backed terminals, ENI-only ones,
the rig's ECAN-Lite), with its EL2008 whose outputs SyncManager lies on the ESC's Digital I/O Output Data
register 0x0F00 (ET1100 data sheet II), as the ESI and the ENI put it. simple_test takes the SyncManager
addresses from the SII (ETG.2010 SyncManager category, SOEM's config_map), so it programs that one at 0x0F00:
it must reach OP and cycle at the working counter it calculates, which is the ENI's own ``Cyclic`` ``Cnt``.
"""

from __future__ import annotations

import re
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from soem_samples import build_soem_sample
from wire_kit import lost_allowed, net_capable, veth_namespace

from gatewaylab.ethercat.eni import parse_eni_xml
from gatewaylab.rig.process import RigProcess

pytestmark = [pytest.mark.net, pytest.mark.slow]

DATA = Path(__file__).with_name("data")
ENI = DATA / "GL-test-line.eni.xml"
CYCLES = 10_000          # simple_test's own count
RIG = """
clock = "realtime"

[[device]]
kind = "ecanlite"
name = "ecan1"

[ethercat]
interface = "{interface}"
eni = "{eni}"
esi = ["{data}"]
"""


@pytest.fixture(scope="module")
def simple_test(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    reason = net_capable()
    if reason is not None:
        pytest.skip(reason)
    program = build_soem_sample("simple_test")
    work = tmp_path_factory.mktemp("eni-soem-c")
    with veth_namespace("gl-enc-", "gln") as (ns, emu, mst):
        path = work / "rig.toml"
        path.write_text(RIG.format(interface=emu, eni=ENI, data=DATA))
        with RigProcess(path, workdir=work, timeout=60) as rig:
            done = subprocess.run(["ip", "netns", "exec", ns, str(program), mst], capture_output=True, text=True,
                                  timeout=600, check=False)
            assert rig.proc.poll() is None, rig.log_text()[-2000:]
            wire = [line for line in rig.log_text().splitlines() if "ethercat-wire" in line]
    yield {"done": done, "wire": wire}


def test_simple_test_reaches_op_at_the_enis_working_counter(simple_test: dict[str, Any]) -> None:
    """simple_test: SAFEOP, OP, then 10,000 cycles, printing each cycle whose working counter reaches the one
    it calculated (outputsWKC * 2 + inputsWKC), here the ENI's two cyclic frames' ``Cnt`` (ETG.2100: 16, the
    EL2008's outputs on 0x0F00 among them). A printed other counter is a wrong answer and fails; a cycle not
    printed had no reply in 2 ms (EC_TIMEOUTRET): counted, printed, tolerated up to 2 % (tests/wire_kit.py)."""
    out = simple_test["done"].stdout
    assert "Operational state reached for all slaves." in out, out[-3000:]
    expected = int(re.search(r"Calculated workcounter (\d+)", out)[1])     # type: ignore[index]
    cycles = re.findall(r"Processdata cycle\s+(\d+), WKC (\d+) ", out)
    wrong = [c for c in cycles if int(c[1]) != expected]
    lost = CYCLES - len({int(c[0]) for c in cycles})
    print(f"expected WKC {expected}; cycles printed {len(cycles)}, not printed (lost) {lost}, wrong WKC "
          f"{len(wrong)}; the rig's wire (frames it dropped late): {simple_test['wire'][-5:]}")
    assert expected == parse_eni_xml(ENI.read_bytes()).cyclic_wkc == 16
    assert not wrong
    assert lost <= lost_allowed(CYCLES)
