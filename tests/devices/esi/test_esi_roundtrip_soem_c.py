"""``gatewaylab esi KIND -o FILE`` and back, as SOEM's own C sample programs see it: each of gatewaylab's
EtherCAT kinds (``ethercat_io``, ``ethercat_drive``, ``ecanlite``, ``esd_can_ethercat``) next to the slave
built from its exported ESI (``kind = "esi"``), in one ``gatewaylab run`` segment on a veth pair.

``slaveinfo IF -map`` (built from the pysoem sdist, tests/ethercat/soem_samples.py) must print the same for
the original and its copy (name, identity, sizes, SyncManagers, FMMUs, mailbox, CoE details and the PDO map
with names and types), apart from what depends on the position in the segment (station address, logical
addresses, ports, delay); ``eepromtool IF N -r FILE`` must read the same SII bytes from both; ``slaveinfo IF
-sdo`` must list the same dictionary (SDO information: every object and entry with name, type, bit length
and access).
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import pytest
from soem_samples import build_soem_sample
from wire_kit import net_capable, veth_namespace

from gatewaylab.rig.process import RigProcess

pytestmark = [pytest.mark.net, pytest.mark.slow]

KINDS = {"ethercat_io": "", "ethercat_drive": "", "ecanlite": 'channels = ["can1"]',
         "esd_can_ethercat": 'bus = "can0"'}
ENTRY = re.compile(r"^(\s+)\[0x([0-9A-F]{4})\.(\d)\](.*)$")
#: lines of slaveinfo that depend on the slave's position, not on the slave
POSITIONAL = ("Slave:", " Configured address", " Delay", " DCParentport", " Activeports", " State")


def _rig(interface: str) -> str:
    text = 'clock = "realtime"\n[[bus]]\nname = "can0"\nbitrate = 500000\n[[bus]]\nname = "can1"\nbitrate = 500000\n'
    for kind, extra in KINDS.items():
        text += f'\n[[device]]\nkind = "{kind}"\nname = "{kind}-orig"\n{extra}\n'
        text += f'\n[[device]]\nkind = "esi"\nesi = "{kind}.xml"\nname = "{kind}-esi"\n'
    return text + f'\n[ethercat]\ninterface = "{interface}"\n'


def slaveinfo_sections(text: str) -> list[list[str]]:
    """Per slave of ``slaveinfo IF -map``, its lines without the positional ones; FMMU logical starts and PDO
    entry addresses made relative (bit offset from the first entry of the same SyncManager)."""
    sections: list[list[str]] = []
    first: int | None = None
    for line in text.splitlines():
        if line.startswith("Slave:"):
            sections.append([])
            continue
        if not sections or not line.strip() or line.startswith(POSITIONAL) or line.startswith("End "):
            continue
        if re.match(r"\s+SM\d ", line):
            first = None
        m = ENTRY.match(line)
        if m is not None:
            bit = int(m[2], 16) * 8 + int(m[3])
            first = bit if first is None else first
            line = f"{m[1]}[+{bit - first}]{m[4]}"
        sections[-1].append(re.sub(r"Ls:[0-9a-f]{8}", "Ls:-", line))
    return sections


@pytest.fixture(scope="module")
def c_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    reason = net_capable()
    if reason is not None:
        pytest.skip(reason)
    slaveinfo, eepromtool = build_soem_sample("slaveinfo"), build_soem_sample("eepromtool")
    work = tmp_path_factory.mktemp("esi-roundtrip-c")
    for kind in KINDS:
        # the SII device name of ethercat_io and ethercat_drive is the rig's name; the gateways' is their product's
        name = ["--name", f"{kind}-orig"] if kind.startswith("ethercat_") else []
        subprocess.run([sys.executable, "-m", "gatewaylab", "esi", kind, *name, "-o", str(work / f"{kind}.xml")],
                       check=True, capture_output=True, timeout=120)
    with veth_namespace("gl-erc-", "glr") as (ns, emu, mst):
        path = work / "rig.toml"
        path.write_text(_rig(emu))
        with RigProcess(path, workdir=work, timeout=90) as rig:
            info = subprocess.run(["ip", "netns", "exec", ns, str(slaveinfo), mst, "-map"],
                                  capture_output=True, text=True, timeout=300, check=False)
            sdo = subprocess.run(["ip", "netns", "exec", ns, str(slaveinfo), mst, "-sdo"],
                                 capture_output=True, text=True, timeout=900, check=False)
            dumps: list[tuple[bytes, str]] = []
            for n in range(1, 2 * len(KINDS) + 1):
                out = work / f"sii-{n}.bin"
                done = subprocess.run(["ip", "netns", "exec", ns, str(eepromtool), mst, str(n), "-r", str(out)],
                                      capture_output=True, text=True, timeout=300, check=False)
                dumps.append((out.read_bytes() if out.exists() else b"", done.stdout))
            assert rig.proc.poll() is None, rig.log_text()[-2000:]
    yield {"slaveinfo": info, "dumps": dumps, "sdo": sdo}


@pytest.mark.parametrize("pair", range(len(KINDS)), ids=list(KINDS))
def test_slaveinfo_cannot_tell_the_copy_from_the_original(c_run: dict[str, Any], pair: int) -> None:
    """Original (position 2k) and its ESI copy (2k+1): slaveinfo -map prints the same slave."""
    done = c_run["slaveinfo"]
    assert done.returncode == 0 and "End slaveinfo" in done.stdout, done.stdout[-3000:] + done.stderr[-2000:]
    sections = slaveinfo_sections(done.stdout)
    assert len(sections) == 2 * len(KINDS), done.stdout[-3000:]
    original, copy = sections[2 * pair], sections[2 * pair + 1]
    print("\n".join(original))
    assert any(line.startswith(" Man:") for line in original)
    assert any("PDO mapping according to" in line for line in original)
    assert sum(1 for line in original if line.lstrip().startswith("[+")) > 0
    assert original == copy


@pytest.mark.parametrize("pair", range(len(KINDS)), ids=list(KINDS))
def test_eepromtool_reads_the_same_sii_bytes(c_run: dict[str, Any], pair: int) -> None:
    """eepromtool -r: the whole SII (its size from word 0x3E, ETG.2010) of the copy is the original's, and its
    checksum (word 7) is the one eepromtool calculates. eepromtool stores 0 for a read that got no answer
    (SOEM's ec_readeepromAP): a differing 4-byte read that is all zero in one dump is a lost frame, counted
    and printed, not a different byte."""
    (a, out_a), (b, out_b) = c_run["dumps"][2 * pair], c_run["dumps"][2 * pair + 1]
    assert len(a) >= 128 and len(a) == len(b), out_a[-1000:] + out_b[-1000:]
    for out in (out_a, out_b):
        checksum = re.search(r"Checksum\s+: ([0-9A-F]{4})\s+calculated\s+: ([0-9A-F]{4})", out)
        assert checksum is not None and checksum[1] == checksum[2], out[-1000:]
    diffs = [i for i in range(0, len(a), 4) if a[i:i + 4] != b[i:i + 4]]
    lost = [i for i in diffs if not any(a[i:i + 4]) or not any(b[i:i + 4])]
    print(f"{len(a)} SII bytes; 4-byte reads lost (0 in one dump): {len(lost)}; differing reads: "
          f"{[(hex(i), a[i:i + 4].hex(), b[i:i + 4].hex()) for i in diffs[:10]]}")
    assert diffs == lost
    assert len(lost) <= len(a) // 4 // 50



def sdo_dictionaries(text: str) -> list[list[str]]:
    """Per slave of ``slaveinfo IF -sdo``: its lines (as :func:`slaveinfo_sections`) with the values read
    removed -- what the dictionary is (object list, names, data types, bit lengths, access), not what the
    firmware behind it has put there since power-on -- and SOEM's error list without its times and slave
    numbers (the same aborts for both)."""
    text = re.sub(r"(\[[^\]\n]*\])[ \t]+\"[^\"]*\"", r"\1", text)
    text = re.sub(r"(\[[^\]\n]*\])[ \t]+[^\n]*", r"\1", text)
    text = re.sub(r"Time:\s+[0-9.]+ ", "", text)
    return slaveinfo_sections(re.sub(r"slave:\d+", "slave:-", text))


@pytest.mark.parametrize("pair", range(len(KINDS)), ids=list(KINDS))
def test_slaveinfo_sdo_lists_the_same_dictionary(c_run: dict[str, Any], pair: int) -> None:
    """slaveinfo -sdo reads each slave's dictionary by SDO information (object list, object and entry
    descriptions, ETG.1000.6) and every entry's value: the copy's dictionary is the original's, object by
    object and entry by entry (name, data type, bit length, access). Values are not compared: a gateway's
    firmware changes its status objects after power-on (the ECAN-Lite's raw registers, the drive's
    statusword), which an ESI cannot carry."""
    done = c_run["sdo"]
    assert done.returncode == 0 and "End slaveinfo" in done.stdout, done.stdout[-3000:] + done.stderr[-2000:]
    sections = sdo_dictionaries(done.stdout)
    assert len(sections) == 2 * len(KINDS)
    original, copy = sections[2 * pair], sections[2 * pair + 1]
    objects = sum(1 for line in original if line.startswith("0x"))
    print(f"{objects} objects, {len(original)} lines")
    assert objects > 10
    assert original == copy
