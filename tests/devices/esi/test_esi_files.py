"""One rig build reads and parses each ESI file once (:class:`EsiFiles`, the build's cache) and builds each
device type's dictionary once; every slave still has a dictionary, outputs and identity of its own.

What the slaves must keep (ETG.1000.6 CoE: every slave serves its own object dictionary; issue 33: "the ESI
device for each slave still gets its own dictionary and state"): 0x1018:04 its own serial number, a SDO
download to one slave changes that slave only, its PDO assignment 0x1C12/0x1C13 its own (ETG.1000.6 PDO
assignment, checked against its own SyncManager), and the outputs an LRW writes are stored in the objects of
the slave whose part of the image they are.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

from gatewaylab.common.build_cache import BuildCache
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esi.device import esi_description
from gatewaylab.devices.esi.eni_segment import EsiCatalogue
from gatewaylab.devices.esi.files import EsiFiles
from gatewaylab.devices.esi.reader import identity_overrides
from gatewaylab.ethercat.description import build_od
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import SdoAbort, SdoAbortCode
from gatewaylab.rig.config import load_rig
from gatewaylab.rig.runtime import Rig

DATA = Path(__file__).with_name("data")
DIGITAL = DATA / "GL-test-EL1xxx-EL2xxx.xml"
ANALOG = DATA / "GL-test-EL3102.xml"


def _esi(type_name: str, name: str, esi: Path = DIGITAL, extra: str = "") -> str:
    return f'[[device]]\nkind = "esi"\nesi = "{esi}"\ntype = "{type_name}"\nname = "{name}"\n{extra}\n'


def _build(tmp_path: Path, text: str, cache: BuildCache | None = None) -> Rig:
    path = tmp_path / "rig.toml"
    path.write_text(f'clock = "simulated"\n{text}')
    return Rig(load_rig(path), build_cache=cache)


def _segment(rig: Rig) -> Segment:
    seg = rig.participants[-1].segment  # type: ignore[attr-defined]
    assert isinstance(seg, Segment)
    return seg


def test_a_build_reads_and_parses_each_file_once(tmp_path: Path) -> None:
    """Six ``kind = "esi"`` sections of two files: two reads, two parses, one dictionary per device type."""
    text = "".join(_esi("EL1859", f"dio{i}") + _esi("EL3102", f"ai{i}", ANALOG) for i in range(3))
    cache = BuildCache()
    with _build(tmp_path, text + '[ethercat]\ninterface = "gl-none"\n', cache) as rig:
        files = cache.part(EsiFiles)
        assert (files.reads, files.parses, files.dictionaries) == (2, 2, 2)
        assert len(_segment(rig).slaves) == 6


def test_a_note_about_a_device_type_is_said_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Three EL1008 from a file that puts their inputs SyncManager on the ESC's registers (0x0F00: the ESC
    refuses it, the reader notes it): the note is logged once for the build, naming the first slave, not once
    per slave."""
    text = DIGITAL.read_text()
    old = 'StartAddress="#x1000">Inputs</Sm>'
    at = text.index(old, text.index(">EL1008<"))
    moved = tmp_path / "moved.xml"
    moved.write_text(text[:at] + old.replace("#x1000", "#x0f00") + text[at + len(old):])
    rig = "".join(_esi("EL1008", f"di{i}", moved) for i in range(3)) + '[ethercat]\ninterface = "gl-none"\n'
    with caplog.at_level(logging.WARNING, logger="gatewaylab.devices.esi.rig"), _build(tmp_path, rig):
        said = [r.getMessage() for r in caplog.records if "0x0F00" in r.getMessage()]
    assert said == [f"di0: {moved.name}: Sm Inputs at 0x0F00 lies on the ESC registers: the ESC refuses it "
                    "(AL status 0x0017 at PREOP -> SAFEOP)"]


def test_eni_sections_and_the_folder_scan_share_the_parse(tmp_path: Path) -> None:
    """An ENI of 12 slaves, the ESI folder scanned for it (two ESI files) and a ``kind = "esi"`` section the ENI
    places at position 2: each file read and parsed once. The three EL3102 slaves (two exact, one of the ENI's
    higher revision) come from one dictionary, yet each shows its own revision in 0x1018:03."""
    (tmp_path / "esi").mkdir()
    for f in (DIGITAL, ANALOG):
        (tmp_path / "esi" / f.name).write_bytes(f.read_bytes())
    (tmp_path / "line.xml").write_bytes((DATA / "GL-test-line.eni.xml").read_bytes())
    text = (_esi("EL1008", "di", tmp_path / "esi" / DIGITAL.name)
            + '[ethercat]\ninterface = "gl-none"\neni = "line.xml"\nesi = ["esi"]\n')
    cache = BuildCache()
    with _build(tmp_path, text, cache) as rig:
        files = cache.part(EsiFiles)
        assert (files.reads, files.parses) == (2, 2)
        # EL1008 for the section; EL1008, EL3102 (revision 0x00140000) and EL2008 for the ENI's slaves
        assert files.dictionaries == 4
        slaves = _segment(rig).slaves
        assert slaves[1].name == "di"
        assert [slaves[p].od.values[(0x1018, 3)] for p in (3, 4, 9)] == [0x00140000, 0x00150000, 0x00140000]


def test_slaves_of_one_type_share_no_dictionary_values_or_outputs(tmp_path: Path) -> None:
    """Two EL1859 and two EL3102 from one dictionary each: the outputs the LRW writes to the first EL1859 reach
    its objects 0x7000..0x7070:01 only; a SDO download to the first EL3102 (0x8000:01 settings, 0x1C13 PDO
    assignment) leaves the second unchanged, and the second still checks its own assignment (0x06040042 past
    its SyncManager's MaxSize); each has its own serial in 0x1018:04."""
    text = (_esi("EL1859", "dio1") + _esi("EL1859", "dio2")
            + _esi("EL3102", "ai1", ANALOG, "serial = 0x1111") + _esi("EL3102", "ai2", ANALOG, "serial = 0x2222")
            + '[ethercat]\ninterface = "gl-none"\n')
    cache = BuildCache()
    with _build(tmp_path, text, cache) as rig:
        assert cache.part(EsiFiles).dictionaries == 2
        clock = rig.clock
        assert isinstance(clock, SimulatedClock)
        seg = _segment(rig)
        dio1, dio2, ai1, ai2 = seg.slaves
        assert dio1.od is not dio2.od and dio1.od.values is not dio2.od.values
        assert all(dio1.od.objects[i] is not dio2.od.objects[i] for i in dio1.od.objects)
        assert (ai1.od.get(0x1018, 4), ai2.od.get(0x1018, 4)) == (0x1111, 0x2222)
        m = Master(clock, seg)
        m.scan()
        for p in range(4):
            m.request_state(p, AlState.PREOP)
        m.sdo_download8(2, 0x8000, 0x01, 1)
        m.sdo_download8(2, 0x1C13, 0, 0)
        m.sdo_download16(2, 0x1C13, 1, 0x1A01)
        m.sdo_download8(2, 0x1C13, 0, 1)
        assert (m.sdo_upload8(2, 0x8000, 0x01), m.sdo_upload8(3, 0x8000, 0x01)) == (1, 0)
        assert (ai1.od.get(0x1C13, 0), ai1.od.get(0x1C13, 1)) == (1, 0x1A01)
        assert (ai2.od.get(0x1C13, 0), ai2.od.get(0x1C13, 1)) == (ai2.od.entries[(0x1C13, 0)].default, 0x1A00)
        m.sdo_download8(3, 0x1C13, 0, 0)
        for i, pdo in enumerate((0x1A00, 0x1A01, 0x1A02), 1):
            m.sdo_download16(3, 0x1C13, i, pdo)
        with pytest.raises(SdoAbort) as exc:
            m.sdo_download8(3, 0x1C13, 0, 3)
        assert exc.value.code == SdoAbortCode.PDO_LENGTH_EXCEEDED
        m.sdo_download8(3, 0x1C13, 0, 2)
        m.config_map()
        m.set_state(AlState.SAFEOP)
        m.set_state(AlState.OP)
        m.image[0] = 0b1010_0101      # dio1's outputs (first in the image); dio2's stay 0
        clock.advance(0.001)
        assert m.exchange_process_data() == m.expected_wkc
        assert [int(dio1.od.get(0x7000 + 0x10 * i, 1)) for i in range(8)] == [1, 0, 1, 0, 0, 1, 0, 1]
        assert [int(dio2.od.get(0x7000 + 0x10 * i, 1)) for i in range(8)] == [0] * 8


def test_a_changed_file_is_read_again(tmp_path: Path) -> None:
    """Keyed by path, modification time and size: an unchanged file is not read twice; a file written since
    is read again, in the same build's cache and in a new build (the new name reaches 0x1008)."""
    esi = tmp_path / "dig.xml"
    original = DIGITAL.read_text()
    esi.write_text(original)
    files = EsiFiles()
    first = files.device(esi, esi.name, "EL1008")
    assert files.device(esi, esi.name, "EL1008") is first and (files.reads, files.parses) == (1, 1)
    renamed = original.replace("EL1008 8K. Dig. Eingang", "EL1008 renamed")
    assert renamed != original
    esi.write_text(renamed)
    st = esi.stat()
    os.utime(esi, ns=(st.st_atime_ns, st.st_mtime_ns + 2_000_000_000))   # a later write, whatever the clock says
    second = files.device(esi, esi.name, "EL1008")
    assert (files.reads, files.parses) == (2, 2)
    assert second.desc.name.startswith("EL1008 renamed") and first.desc.name != second.desc.name
    text = _esi("EL1008", "di", esi) + '[ethercat]\ninterface = "gl-none"\n'
    with _build(tmp_path, text) as rig:
        assert str(_segment(rig).slaves[0].od.get(0x1008)).startswith("EL1008 renamed")
    esi.write_text(original)
    os.utime(esi, ns=(st.st_atime_ns, st.st_mtime_ns + 4_000_000_000))
    with _build(tmp_path, text) as rig:
        assert _segment(rig).slaves[0].od.get(0x1008) == first.desc.name


def test_the_catalogue_reads_through_the_cache(tmp_path: Path) -> None:
    """The ``[ethercat] esi`` folder scan reads every XML file once through the injected reader; a slave
    matched twice by identity gets the device read once."""
    read: list[Path] = []

    def counting(path: Path) -> bytes:
        read.append(path)
        return path.read_bytes()

    files = EsiFiles(counting)
    catalogue = EsiCatalogue([DATA], files)
    assert sorted(p.name for p in read) == sorted(p.name for p in DATA.glob("*.xml"))
    found = catalogue.match(2, 0x0C1E3052, 0x00140000)
    again = catalogue.match(2, 0x0C1E3052, 0x00140000)
    assert found is not None and again is not None and found[0] is again[0]
    assert len(read) == 3 and files.parses == 3


@pytest.mark.parametrize("serial", [None, 0, 0x1234])
@pytest.mark.parametrize("path", [DIGITAL, ANALOG], ids=lambda p: p.stem)
def test_a_copied_dictionary_is_the_one_build_od_makes(path: Path, serial: int | None) -> None:
    """For every device of the test files: the copy of the type's dictionary has the rows, values and checked
    objects ``build_od`` gives the slave's own description (the serial in 0x1018:04 only when set)."""
    files = EsiFiles()
    _key, root = files.root(path, path.name)
    identities = [((t.text or "").strip(), int(t.get("ProductCode", "")[2:], 16), int(t.get("RevisionNo", "")[2:], 16))
                  for t in root.iter("Type") if t.get("ProductCode")]
    assert identities
    for type_name, product, revision in identities:
        device = files.device(path, path.name, type_name, product, revision)
        desc = esi_description(device, serial)
        built = build_od(desc)
        copied = files.dictionary(device, desc, identity_overrides(serial))
        assert copied.entries == built.entries and copied.values == built.values, type_name
        assert {i: o.entries for i, o in copied.objects.items()} == {i: o.entries for i, o in built.objects.items()}
        assert copied.intercepted == built.intercepted and copied.intercepted
    assert files.dictionaries == len(identities)
