"""``gatewaylab lss`` from another process, as a student runs it on a rig (issue 14, "Learn": every CiA 305
service as the IDX guide lists it, ``--explain`` printing the frames with their meaning, addresses in hex)."""

import json
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest

from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
[[drive]]
bus = "can0"
serial = 0x00C0FFEE       # unconfigured
"""


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[RigProcess]:
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, workdir=tmp_path, timeout=30) as process:
        yield process


def lss(rig: RigProcess, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "lss", str(rig.ready_file), *args],
                          capture_output=True, text=True, timeout=120, check=False)


def test_fastscan_then_node_id_then_store_like_the_exercise(rig: RigProcess) -> None:
    """CiA 305 Fastscan (IDX guide 3.5.3): the bisection finds the unconfigured drive's 128-bit address,
    narrated bit by bit with --explain; configure node-ID 4 and store; after switch state global waiting
    the drive answers SDO as node 4 with the serial Fastscan found."""
    out = lss(rig, "fastscan", "--node-id", "4", "--store", "--explain")
    assert out.returncode == 0, out.stderr
    found = re.search(r"found vendor 0x([0-9A-F]{8}) product 0x([0-9A-F]{8}) revision 0x([0-9A-F]{8}) "
                      r"serial 0x([0-9A-F]{8})", out.stdout)
    assert found is not None and int(found.group(4), 16) == 0x00C0FFEE
    # the narrated bisection spells the same address: 4 x 32 steps, most significant bit first
    bits = re.findall(r"bit (\d+) of (vendor|product|revision|serial): ([01])", out.stdout)
    assert len(bits) == 128
    parts = {"vendor": 0, "product": 0, "revision": 0, "serial": 0}
    for bit, part, value in bits:
        parts[part] |= int(value) << int(bit)
    assert [parts[p] for p in ("vendor", "product", "revision", "serial")] == [int(g, 16) for g in found.groups()]
    assert "-> 7E5 51" in out.stdout and "<- 7E4 4F" in out.stdout
    assert "node-ID 0x04 (4) configured" in out.stdout and "configuration stored" in out.stdout
    assert lss(rig, "switch-global", "waiting").returncode == 0

    network = canopen.Network()
    network.connect(interface="gatewaylab", channel=rig.endpoint("can0"))
    try:
        serial = network.add_node(4).sdo.upload(0x1018, 4)
    finally:
        network.disconnect()
    assert int.from_bytes(serial, "little") == 0x00C0FFEE


def test_selective_inquire_identify_services(rig: RigProcess) -> None:
    """Switch state selective by the full LSS address (CiA 305 8.3.2), inquire services (8.3.4), identify
    remote slave with revision/serial ranges (8.3.5; the configured drive takes part once NMT-stopped, IDX
    guide 3.5) and identify non-configured slaves, results in --json."""
    first = json.loads(lss(rig, "--json", "fastscan").stdout)["result"]
    assert first["serial"] == 0x00C0FFEE
    assert lss(rig, "switch-global", "waiting").returncode == 0
    address = [hex(first[k]) for k in ("vendor", "product", "revision", "serial")]
    selected = lss(rig, "switch-selective", *address)
    assert selected.returncode == 0 and "now in configuration state" in selected.stdout
    values = json.loads(lss(rig, "--json", "inquire", "all").stdout)["result"]
    assert values == {"vendor": first["vendor"], "product": first["product"], "revision": first["revision"],
                      "serial": 0x00C0FFEE, "node-id": 0xFF}
    assert lss(rig, "switch-global", "waiting").returncode == 0
    count = json.loads(lss(rig, "--json", "identify-unconfigured").stdout)["result"]
    assert count == 1
    # IDX guide 3.5: a configured drive serves LSS only in NMT Stopped
    network = canopen.Network()
    network.connect(interface="gatewaylab", channel=rig.endpoint("can0"))
    try:
        network.nmt.state = "STOPPED"
    finally:
        network.disconnect()
    # both drives share vendor/product/revision; serial range 0x1000..0x1FFF holds only drive 2
    ranged = lss(rig, "--json", "identify", hex(first["vendor"]), hex(first["product"]), "0", "0xFFFFFFFF",
                 "0x1000", "0x1FFF")
    assert json.loads(ranged.stdout)["result"] == 1
    wide = lss(rig, "--json", "identify", hex(first["vendor"]), hex(first["product"]), "0", "0xFFFFFFFF",
               "0", "0xFFFFFFFF")
    assert json.loads(wide.stdout)["result"] == 2


def test_unhappy_paths_say_one_line(rig: RigProcess, tmp_path: Path) -> None:
    """No slave selected -> configure node-ID gets no answer (exit 1, one line); an unknown address ->
    exit 1; a ready file without that bus, garbage numbers and out-of-range ids -> exit 2."""
    out = lss(rig, "set-node-id", "5")
    assert out.returncode == 1 and out.stderr.strip().startswith("error: no slave in LSS configuration state answered")
    assert "switch-selective" in out.stderr and "Traceback" not in out.stderr
    out = lss(rig, "switch-selective", "1", "2", "3", "4")
    assert out.returncode == 1 and "no slave with vendor 0x00000001" in out.stdout
    out = lss(rig, "--bus", "can9", "store")
    assert out.returncode == 2 and "no bus 'can9'" in out.stderr
    for bad in (["set-node-id", "0x80x"], ["set-node-id", "0"], ["set-node-id", "128"], ["set-bit-timing", "12"]):
        out = lss(rig, *bad)
        assert out.returncode == 2 and "Traceback" not in out.stderr, bad
