"""The MasterBackend contract (docs/ethercat-host.md) against both backends.

Every ``ec_contract.check_*`` runs against :class:`InProcessBackend` on a simulated clock and,
with root, against :class:`PysoemBackend` (SOEM) in a network namespace over a veth pair whose
other end the emulator's wire thread serves. Emulator-side facts (the FoE store, SYNC0 pulses)
are checked here on the segment after the run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from ec_contract import CHECKS, FOE_PAYLOAD, SLAVES

from gatewaylab.common.clock import Clock, RealTimeClock, SimulatedClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.errors import AlStatusCode, MasterError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.hosts.ethercat.shared import al_status_name
from gatewaylab.rig.runtime import Rig

DRIVER = Path(__file__).with_name("ec_backend_driver.py")
Runner = Callable[[str], tuple[dict[str, Any], Segment]]


def make_segment(clock: Clock) -> Segment:
    return Segment([create_io_slave(clock, name, serial=serial, revision=rev) for name, serial, rev in SLAVES])


def _run_inprocess(check: str) -> tuple[dict[str, Any], Segment]:
    clock = SimulatedClock()
    segment = make_segment(clock)
    backend = InProcessBackend(Master(clock, segment))
    try:
        return CHECKS[check](backend), segment
    finally:
        backend.close()


@pytest.fixture(params=["inprocess", pytest.param("pysoem", marks=[pytest.mark.net, pytest.mark.slow])])
def run(request: pytest.FixtureRequest) -> Runner:
    if request.param == "inprocess":
        return _run_inprocess
    veth = request.getfixturevalue("veth_ns")

    def run_pysoem(check: str) -> tuple[dict[str, Any], Segment]:
        clock = RealTimeClock()
        segment = make_segment(clock)
        wire = WireTransport(segment, veth.emulator_iface, clock, drive_clock=True)
        wire.start()
        try:
            proc = subprocess.run(["ip", "netns", "exec", veth.namespace, sys.executable, str(DRIVER),
                                   veth.master_iface, check], capture_output=True, text=True, timeout=120,
                                  check=False)
        finally:
            wire.stop()
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert not wire.errors
        return json.loads(proc.stdout.strip().splitlines()[-1]), segment

    return run_pysoem


@pytest.mark.parametrize("check", sorted(set(CHECKS) - {"foe", "dc"}))
def test_contract(run: Runner, check: str) -> None:
    """One contract check (its docstring quotes the spec section) through this backend."""
    run(check)


def test_contract_foe_reaches_the_slave_store(run: Runner) -> None:
    """FoE write lands in the slave's file store byte for byte (ETG.1000.6 FoE write)."""
    result, segment = run("foe")
    assert segment.slaves[0].foe_handler.files[result["written"]] == FOE_PAYLOAD  # type: ignore[attr-defined]


def test_contract_dc_sync0_pulses(run: Runner) -> None:
    """configure_dc programs SYNC0 (1 ms): every slave counts pulses while the master cycles."""
    _result, segment = run("dc")
    assert all(s.app.sync0_count > 20 for s in segment.slaves)  # type: ignore[attr-defined]


# ------------------------------------------------------------------ in-process specifics
def _rig(tmp_path: Path) -> Rig:
    path = tmp_path / "rig.toml"
    path.write_text('clock = "simulated"\n[[device]]\nkind = "ethercat_io"\nname = "io-a"\n'
                    '[[device]]\nkind = "ethercat_io"\nname = "io-b"\nserial = 7\n'
                    '[ethercat]\ninterface = "gl-none"\n')
    return Rig.from_file(path)


def test_from_rig_brings_the_segment_to_preop(tmp_path: Path) -> None:
    """from_rig: the rig's [ethercat] segment in file order, scanned and in PREOP (IgH's default)."""
    with _rig(tmp_path) as rig:
        rig.start()
        b = InProcessBackend.from_rig(rig)
        assert isinstance(b, MasterBackend)
        assert b.clock is rig.clock
        assert [(s.position, s.name, s.serial) for s in b.slaves()] == [(0, "io-a", 0), (1, "io-b", 7)]
        assert [b.state(i) for i in range(2)] == [(AlState.PREOP, 0)] * 2
        assert b.sdo_upload(1, 0x1008, 0) == b"io-b"


def test_from_rig_without_ethercat_devices_is_refused(tmp_path: Path) -> None:
    """A rig without EtherCAT devices has nothing to master: a local error naming it."""
    path = tmp_path / "rig.toml"
    path.write_text('clock = "simulated"\n[[bus]]\nname = "can0"\nendpoint = "none"\n')
    with Rig.from_file(path) as rig, pytest.raises(MasterError, match="no EtherCAT devices"):
        InProcessBackend.from_rig(rig)


def test_timeout_is_the_builtin_timeout_error() -> None:
    """A slave that stops answering: MasterTimeout, also catchable as the builtin TimeoutError."""
    clock = SimulatedClock()
    segment = make_segment(clock)
    alive = [True]

    def link(raw: bytes) -> bytes | None:
        buf = bytearray(raw)
        return bytes(buf) if alive[0] and segment.process(buf) else None

    b = InProcessBackend(Master(clock, link=link))
    alive[0] = False
    with pytest.raises(TimeoutError):
        b.sdo_upload(0, 0x1008, 0)
    with pytest.raises(MasterTimeout):
        b.foe_read(0, "x")
    assert clock.now() < 1.0      # waited on the simulated clock, bounded by the mailbox timeout


def test_wkc_mismatch_is_counted() -> None:
    """A slave whose process data is lost: exchange reports the short working counter and counts it."""
    clock = SimulatedClock()
    segment = make_segment(clock)
    b = InProcessBackend(Master(clock, segment))
    b.config_map()
    b.request_state(AlState.SAFEOP)
    b.request_state(AlState.OP)
    assert b.exchange() == (9, 9) and b.wkc_errors == 0
    b.master.fpwr(0x1003, 0x0600, bytes(32))    # slave 2's FMMUs off: it no longer counts
    wkc, expected = b.exchange()
    assert (wkc, expected) == (6, 9) and b.wkc_errors == 1


def test_al_status_name() -> None:
    """AL status codes by name (ETG.1000.6 table 'AL Status Codes')."""
    assert al_status_name(AlStatusCode.SM_WATCHDOG) == "0x001B SM_WATCHDOG"
    assert al_status_name(0x7777) == "0x7777"
