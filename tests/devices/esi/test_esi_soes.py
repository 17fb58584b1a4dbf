"""ESI files nobody here wrote: SOES's sample device descriptions (OpenEtherCATsociety/SOES, applications/*/*.xml).

SOES is GPLv2, so its files are not kept in this repository: point ``GATEWAYLAB_SOES`` at a SOES checkout
(``git clone https://github.com/OpenEtherCATsociety/SOES``) and every ESI in it is run as ``kind = "esi"``
and brought to OP by the in-process master, cycling with the expected working counter. They differ from
the vendors' files in ways a reader must take: no ``DefaultSize`` on the process data SyncManagers, no
``PdoMapping`` flags, ``DefaultValue`` in hex, an assignment whose subindex 0 counts empty entries, repeated
``Info`` names.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esi.device import esi_slave
from gatewaylab.devices.esi.reader import read_esi_file
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

SOES = os.environ.get("GATEWAYLAB_SOES", "")
FILES = sorted(Path(SOES).glob("applications/*/*.xml")) if SOES else []


@pytest.mark.skipif(not FILES, reason="GATEWAYLAB_SOES does not name a SOES checkout (GPLv2: not kept here)")
@pytest.mark.parametrize("path", FILES, ids=[f"{p.parent.name}/{p.name}" for p in FILES])
def test_soes_sample_esi_reaches_op(path: Path) -> None:
    clock = SimulatedClock()
    device = read_esi_file(path)
    slave = esi_slave(clock, device, device.type_name)
    m = Master(clock, Segment([slave]))
    m.bring_up()
    for _ in range(10):
        clock.advance(0.001)
        assert m.exchange_process_data() == m.expected_wkc
    info = m.slave(0).sii
    assert (info.vendor_id, info.product_code) == (device.desc.vendor_id, device.desc.product_code)
