"""``gatewaylab esi KIND -o FILE`` and back: the ESI gatewaylab exports for each of its EtherCAT kinds, run
as ``kind = "esi"``, gives a slave a master cannot tell from the original: the same SII bytes (read through
the EEPROM interface, ETG.1000.4 SII access), the same PDO map (0x1C12/0x1C13 and every assigned PDO's
mapping read over CoE, as SOEM's ``slaveinfo -map`` reads it) and the same dictionary (the SDO information
object list, every object description and every entry description, ETG.1000.6 SDO information service)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.cli.esi import ESI_KINDS, kind_slave
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esi.device import esi_slave
from gatewaylab.devices.esi.reader import read_esi_file
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import SdoAbort


def _view(m: Master, position: int, sdo_info: bool) -> dict[str, Any]:
    """What a master learns of one slave: SII, PDO map by CoE, and (``sdo_info``) the dictionary."""
    station = m.slave(position).station
    out: dict[str, Any] = {"sii": m.read_sii(station)}
    pdo_map = []
    for assign in (0x1C12, 0x1C13):
        for i in range(1, m.sdo_upload8(position, assign, 0) + 1):
            pdo = m.sdo_upload16(position, assign, i)
            pdo_map.append((assign, pdo, [m.sdo_upload32(position, pdo, j)
                                          for j in range(1, m.sdo_upload8(position, pdo, 0) + 1)]))
    out["pdo_map"] = pdo_map
    if sdo_info:
        objects = m.od_list(position)
        descs = []
        for index in objects:
            d = m.object_description(position, index)
            subs = range(d.max_subindex + 1)
            entries: list[object] = []
            for sub in subs:
                try:
                    entries.append(m.entry_description(position, index, sub))
                except SdoAbort as exc:      # a gap in a record: the same abort on both
                    entries.append(repr(exc))
            descs.append((d, entries))
        out["dictionary"] = descs
    return out


@pytest.mark.parametrize("kind", sorted(ESI_KINDS))
def test_exported_esi_runs_as_the_original(tmp_path: Path, kind: str) -> None:
    esi = tmp_path / f"{kind}.xml"
    done = subprocess.run([sys.executable, "-m", "gatewaylab", "esi", kind, "-o", str(esi)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"{esi}: ESI of {kind}")
    clock = SimulatedClock()
    original = kind_slave(kind)
    device = read_esi_file(esi)
    copy = esi_slave(clock, device, original.name)
    # the dictionaries, row by row (names, types, access, PDO mapping, PREOP-only writes, defaults)
    rows = [[(e.key, e.name, e.data_type, e.access.readable, e.access.writable, e.rx_pdo, e.tx_pdo,
              e.preop_only and e.access.writable, s.od.get_bytes(e.index, e.subindex))
             for o in s.od for _sub, e in sorted(o.entries.items())] for s in (original, copy)]
    assert rows[0] == rows[1]
    assert [(o.index, o.name, o.object_code) for o in original.od] == [
        (o.index, o.name, o.object_code) for o in copy.od]
    # and what a master reads online; a large dictionary (ECAN-Lite: 2500 entries) is browsed in part
    segment = Segment([kind_slave(kind), copy])
    m = Master(SimulatedClock(), segment)
    m.scan()
    for p in (0, 1):
        m.request_state(p, AlState.PREOP)
    views = [_view(m, p, sdo_info=len(original.od) < 200) for p in (0, 1)]
    assert views[0]["sii"] == views[1]["sii"]
    assert views[0]["pdo_map"] == views[1]["pdo_map"]
    assert views[0].get("dictionary") == views[1].get("dictionary")
    assert m.od_list(0) == m.od_list(1)


def test_configurable_mapping_of_the_copy_is_checked(tmp_path: Path) -> None:
    """ETG.1000.6 PDO mapping in PREOP on the ESI copy of ``ethercat_io`` (configurable RxPDO 0x1600): entries
    change only while subindex 0 is 0 (else 0x06010003 'subindex cannot be written'), an
    object that cannot be mapped aborts 0x06040041; the master's new mapping is what SAFEOP runs."""
    esi = tmp_path / "io.xml"
    subprocess.run([sys.executable, "-m", "gatewaylab", "esi", "ethercat_io", "-o", str(esi)], check=True,
                   capture_output=True, timeout=120)
    clock = SimulatedClock()
    m = Master(clock, Segment([esi_slave(clock, read_esi_file(esi), "io")]))
    m.scan()
    m.request_state(0, AlState.PREOP)
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download32(0, 0x1600, 1, 0x70000108)
    assert exc.value.code == 0x06010003
    m.sdo_download8(0, 0x1600, 0, 0)
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download32(0, 0x1600, 1, 0x60000108)      # an input: not an RxPDO object
    assert exc.value.code == 0x06040041
    m.sdo_download32(0, 0x1600, 1, 0x70000108)
    m.sdo_download8(0, 0x1600, 0, 1)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    assert m.slave(0).output_bytes == 1
