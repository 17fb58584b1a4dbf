"""The frame and working-counter faults from the pytest plugin (``RigHandle.fault``, docs/rig.md): on a
simulated-clock rig the in-process master sees them exactly, cycle by cycle (docs/faults.md "EtherCAT faults";
ETG.1000.4: the working counter a frame comes back with, a frame that never comes back)."""

from __future__ import annotations

import pytest

from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.rig.faults_core import FaultRefused

RIG = {"device": [{"kind": "ethercat_io", "name": "io1"}, {"kind": "ethercat_io", "name": "io2", "serial": 7}],
       "ethercat": {"interface": "gl-none"}}


def test_fault_verbs_through_the_fixture(gatewaylab_rig) -> None:
    """handle.fault("ec-wkc", ...): exactly 3 cycles read WKC - 1; handle.fault("ec-lose", ...): the next 2
    cycles are lost (WKC 0) and the master counts them; ec-outputs-off io2 with a duration: the LRW counts
    2 less until it ends on the simulated clock; a refused fault raises FaultRefused."""
    handle = gatewaylab_rig(RIG, clock="simulated")
    backend = InProcessBackend.from_rig(handle.rig)
    master = backend.master
    master.bring_up()
    full = master.exchange_process_data()
    assert full == master.expected_wkc
    answer = handle.fault("ec-wkc", offset=-1, count=3, cmd="LRW")
    assert answer["fault"] == "ec-wkc" and answer["left"] == 3
    assert [master.exchange_process_data() for _ in range(4)] == [full - 1] * 3 + [full]
    lost = master.lost_frames
    handle.fault("ec-lose", count=2, cmd="LRW")
    assert [master.exchange_process_data() for _ in range(3)] == [0, 0, full]
    assert master.lost_frames == lost + 2
    handle.fault("ec-outputs-off", device="io2", seconds=0.05)
    assert handle.rig.faults.ethercat_states()["faults"][0]["target"] == "io2"
    assert master.exchange_process_data() == full - 2
    handle.clock.advance(0.06)
    assert master.exchange_process_data() == full
    with pytest.raises(FaultRefused):
        handle.fault("ec-lose", count=0)
