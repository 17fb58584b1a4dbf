"""``canopen_node`` from EDS files nobody here wrote: python canopen's own ``test/sample.eds`` and
``examples/eds/e35.eds`` (its source distribution, fetched for the installed version at test time),
each run through ``gatewaylab run`` and read by python canopen loading the same file, as its users
ask for a slave that runs from an EDS (canopen issues 550, 555)."""

from __future__ import annotations

import importlib.metadata
import json
import struct
import subprocess
import sys
import tarfile
import time
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODVariable

from gatewaylab.rig.process import RigProcess

ROOT = Path(__file__).resolve().parents[3]
#: the sdists `make conformance` downloads too (conformance/run.py): fetched once per machine
SDISTS = ROOT / ".venv" / "conformance" / "sdist"
FILES = {"sample": "test/sample.eds", "e35": "examples/eds/e35.eds"}


def _canopen_sdist() -> Path:
    version = importlib.metadata.version("canopen")
    SDISTS.mkdir(parents=True, exist_ok=True)
    tarball = SDISTS / f"canopen-{version}.tar.gz"
    if not tarball.exists():
        done = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary",
                               ":all:", f"canopen=={version}", "-d", str(SDISTS)],
                              capture_output=True, text=True, timeout=600, check=False)
        if done.returncode != 0 or not tarball.exists():
            pytest.skip(f"the canopen {version} sdist cannot be downloaded here: {done.stderr.strip()[-200:]}")
    return tarball


@pytest.fixture(scope="module")
def eds_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("canopen-eds")
    with tarfile.open(_canopen_sdist()) as tar:
        for name, inner in FILES.items():
            member = next(m for m in tar.getmembers() if m.name.endswith("/" + inner))
            data = tar.extractfile(member)
            assert data is not None
            (folder / f"{name}.eds").write_bytes(data.read())
    return {name: folder / f"{name}.eds" for name in FILES}


RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 500000

[[device]]
kind = "canopen_node"
eds = "sample.eds"         # node-ID from its [DeviceComissioning] NodeID = 0x10
bus = "can0"

[[device]]
kind = "canopen_node"
eds = "e35.eds"
bus = "can0"
node_id = 35
"""


@pytest.fixture(scope="module")
def rig(eds_files: dict[str, Path]) -> Iterator[RigProcess]:
    folder = eds_files["sample"].parent
    (folder / "rig.toml").write_text(RIG)
    with RigProcess(folder / "rig.toml", workdir=folder, timeout=60) as process:
        yield process


@pytest.fixture
def network(rig: RigProcess) -> Iterator[canopen.Network]:
    net = canopen.Network()
    net.connect(interface="gatewaylab", channel=rig.endpoint("can0"))
    try:
        yield net
    finally:
        net.disconnect()


def _expected(var: ODVariable) -> object:
    default = var.default
    if var.data_type == 0x08 and isinstance(default, float):     # REAL32 on the wire
        return struct.unpack("<f", struct.pack("<f", default))[0]
    return default


@pytest.mark.parametrize(("name", "node_id"), [("sample", 0x10), ("e35", 35)])
def test_every_readable_object_reads_back_its_eds_default(network: canopen.Network, eds_files: dict[str, Path],
                                                          name: str, node_id: int) -> None:
    """CiA 306: the EDS DefaultValue is the value after power-on; each readable entry (SDO upload, CiA 301
    7.2.4.3) returns it to a client that loaded the same EDS. Data type objects of [DummyUsage] read
    as their length in bits (CiA 301 7.4.7.1)."""
    node = network.add_node(node_id, str(eds_files[name]))
    checked = 0
    wrong: list[str] = []
    for obj in node.object_dictionary.values():
        for var in [obj] if isinstance(obj, ODVariable) else list(obj.values()):
            if "r" not in var.access_type and var.access_type != "const":
                continue
            raw = node.sdo.upload(var.index, var.subindex)
            expected = _expected(var)
            checked += 1
            if expected is None:
                continue
            value = var.decode_raw(raw)
            if value != expected:
                wrong.append(f"0x{var.index:04X}:{var.subindex} {var.name}: {value!r} != {expected!r}")
    assert checked > 90 and not wrong, wrong


def test_tpdos_are_the_eds_configuration_and_sync_ones_arrive(network: canopen.Network,
                                                              eds_files: dict[str, Path]) -> None:
    """e35.eds configures TPDO 1..3 synchronous (transmission type 1, CiA 301 7.2.2.2): node.tpdo.read()
    over SDO gives its COB-IDs ($NODEID+0x180.. for node 35), types and mappings; after NMT start every
    SYNC brings each of them."""
    node = network.add_node(35, str(eds_files["e35"]))
    od = node.object_dictionary
    node.tpdo.read()
    sync_maps = []
    for n, pdo in node.tpdo.map.items():
        comm, mapping = od[0x1800 + n - 1], od[0x1A00 + n - 1]
        assert pdo.cob_id == comm[1].default & 0x7FF
        assert pdo.trans_type == comm[2].default
        count = mapping[0].default
        assert [(v.index << 16) | (v.subindex << 8) | v.length for v in pdo.map] == \
            [mapping[sub].default for sub in range(1, count + 1)]
        if pdo.enabled and pdo.map and 1 <= pdo.trans_type <= 240:
            sync_maps.append(pdo)
    assert [p.cob_id for p in sync_maps] == [0x180 + 35, 0x280 + 35, 0x380 + 35]
    got: list[int] = []
    for pdo in sync_maps:
        pdo.add_callback(lambda message: got.append(message.cob_id))
    node.nmt.state = "OPERATIONAL"
    deadline = time.monotonic() + 10
    while len(set(got)) < 3 and time.monotonic() < deadline:
        network.sync.transmit()
        time.sleep(0.01)
    assert sorted(set(got)) == [0x180 + 35, 0x280 + 35, 0x380 + 35]
    node.nmt.state = "PRE-OPERATIONAL"


def test_the_ready_file_lists_each_node_with_its_file(rig: RigProcess, eds_files: dict[str, Path]) -> None:
    """`gatewaylab monitor` and `gatewaylab sdo --eds` find each node's dictionary in the ready file."""
    nodes = json.loads(Path(rig.ready_file).read_text())["canopen"]["can0"]
    by_id = {info["node_id"]: info for info in nodes.values()}
    assert set(by_id) == {0x10, 35}
    assert by_id[35]["source"] == str(eds_files["e35"])
    assert Path(by_id[0x10]["eds"]).read_text().startswith("[FileInfo]")
