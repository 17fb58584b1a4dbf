"""The ESI's AL state machine timeouts (ETG.2000 ``<Info><StateMachine><Timeout>``) on a slave whose application
the rig makes slow (``transition_ms``), as Beckhoff's slave stack handles them (SSC ``ecatslv.c``: a pending
transition keeps AL status at the present state; its ESM timeout is the ESI's less 10 %; when it runs out the
transition is refused with the error flag and 0x0001, or 0x001B for SAFEOP->OP without DC).

In process on a simulated clock (the times exact), and once on the user's path: ``gatewaylab run`` with pysoem
on a veth pair (default timeouts).
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from wire_kit import net_capable, veth_namespace

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esi.device import EsiApplication, esi_slave
from gatewaylab.devices.esi.esm import parse_transition_ms
from gatewaylab.devices.esi.reader import read_esi_file
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.process import RigProcess

DATA = Path(__file__).with_name("data")
EL3102 = DATA / "GL-test-EL3102.xml"        # PreopTimeout 2000, SafeopOpTimeout 9000 (ms)
AL_CONTROL = 0x0120
ERR = 0x10


def _master(slow: dict[str, float]) -> tuple[SimulatedClock, Master]:
    clock = SimulatedClock()
    device = read_esi_file(EL3102, "EL3102")
    slave = esi_slave(clock, device, "ai", transition_ms=parse_transition_ms(slow, "test"))
    m = Master(clock, Segment([slave]))
    m.scan()
    return clock, m


def _request(m: Master, state: AlState, ack: bool = False) -> None:
    m.fpwr(m.slave(0).station, AL_CONTROL, struct.pack("<H", int(state) | (ERR if ack else 0)))


def test_the_reader_keeps_the_esi_timeouts() -> None:
    assert read_esi_file(EL3102, "EL3102").timeouts == {
        "PreopTimeout": 2000, "SafeopOpTimeout": 9000, "BackToInitTimeout": 5000, "BackToSafeopTimeout": 200}


def test_a_slow_transition_within_the_timeout_is_pending_then_done() -> None:
    """PREOP->SAFEOP taking 500 ms (SafeopOpTimeout 9000 ms): AL status stays PREOP without error until then."""
    clock, m = _master({"PREOP_SAFEOP": 500})
    m.request_state(0, AlState.PREOP)
    m.config_map()
    t0 = clock.now()
    _request(m, AlState.SAFEOP)
    assert m.al_status(0) == (AlState.PREOP, 0)
    clock.run_until(t0 + 0.4999)
    _request(m, AlState.SAFEOP)                  # a master repeating its request does not restart the time
    assert m.al_status(0) == (AlState.PREOP, 0)
    clock.run_until(t0 + 0.5)
    assert m.al_status(0) == (AlState.SAFEOP, 0)


@pytest.mark.parametrize(("slow", "start", "target", "limit", "code"), [
    ({"INIT_PREOP": 1900}, AlState.INIT, AlState.PREOP, 1.8, 0x0001),          # PreopTimeout 2000 - 10 %
    ({"PREOP_SAFEOP": 9000}, AlState.PREOP, AlState.SAFEOP, 8.1, 0x0001),      # SafeopOpTimeout 9000 - 10 %
    ({"SAFEOP_OP": 20000}, AlState.SAFEOP, AlState.OP, 8.1, 0x001B),           # no DC: SM watchdog
], ids=["INIT_PREOP", "PREOP_SAFEOP", "SAFEOP_OP"])
def test_a_transition_longer_than_the_esi_allows_is_refused(slow: dict[str, float], start: AlState,
                                                            target: AlState, limit: float, code: int) -> None:
    """Pending until the ESI's timeout less 10 %, then the present state with the error flag and SSC's code;
    the master acknowledges (ETG.1000.6: error indication left with the acknowledge bit)."""
    clock, m = _master(slow)
    if start != AlState.INIT:
        m.request_state(0, AlState.PREOP)
        m.config_map()
    else:
        m.config.configure_mailbox(m.slave(0))      # SM0/SM1 as the SII says, before PREOP is requested
    if start == AlState.SAFEOP:
        m.request_state(0, AlState.SAFEOP)
    t0 = clock.now()
    _request(m, target)
    clock.run_until(t0 + limit - 0.001)
    assert m.al_status(0) == (start, 0)
    clock.run_until(t0 + limit)
    assert m.al_status(0) == (start | ERR, code)
    _request(m, start, ack=True)
    assert m.al_status(0) == (start, 0)
    app = m.segment.slaves[0].app
    assert isinstance(app, EsiApplication) and app.esm.refused == [((start, target), code)]


def test_a_downward_request_ends_a_pending_transition() -> None:
    """INIT while PREOP->SAFEOP is pending: done at once, and the pending transition never completes."""
    clock, m = _master({"PREOP_SAFEOP": 500})
    m.request_state(0, AlState.PREOP)
    m.config_map()
    t0 = clock.now()
    _request(m, AlState.SAFEOP)
    _request(m, AlState.INIT)
    assert m.al_status(0) == (AlState.INIT, 0)
    clock.run_until(t0 + 10)
    assert m.al_status(0) == (AlState.INIT, 0)


def test_transition_ms_rejects_what_it_does_not_know() -> None:
    with pytest.raises(ConfigError, match="OP_SAFEOP"):
        parse_transition_ms({"OP_SAFEOP": 10}, "[[device]] x")
    with pytest.raises(ConfigError, match="milliseconds"):
        parse_transition_ms({"SAFEOP_OP": -1}, "[[device]] x")


RIG = """
clock = "realtime"

[[device]]
kind = "esi"
esi = "fast.xml"
type = "EL1008"
name = "slow-ok"
transition_ms = {{ PREOP_SAFEOP = 300 }}

[[device]]
kind = "esi"
esi = "fast.xml"
type = "EL1008"
name = "too-slow"
transition_ms = {{ PREOP_SAFEOP = 5000 }}

[ethercat]
interface = "{interface}"
"""
SOEM = """
import json, sys, pysoem
m = pysoem.Master()
m.open(sys.argv[1])
n = m.config_init()
m.config_map()
m.state_check(pysoem.SAFEOP_STATE, 3_000_000)
m.read_state()
print(json.dumps([n] + [[s.state, s.al_status] for s in m.slaves]))
m.close()
"""


@pytest.mark.net
@pytest.mark.slow
def test_soem_sees_the_refusal_through_gatewaylab_run(tmp_path: Path) -> None:
    """An ESI with SafeopOpTimeout 1000 ms: the slave whose application needs 300 ms reaches SAFEOP, the one
    that needs 5 s shows PREOP + error, AL status code 0x0001, to SOEM's config_map/state_check (3 s)."""
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    text = (DATA / "GL-test-EL1xxx-EL2xxx.xml").read_text(encoding="utf-8")
    (tmp_path / "fast.xml").write_text(text.replace("<SafeopOpTimeout>9000<", "<SafeopOpTimeout>1000<"),
                                       encoding="utf-8")
    (tmp_path / "soem.py").write_text(SOEM)
    with veth_namespace("gl-esm-", "gsm") as (ns, emu, mst):
        (tmp_path / "rig.toml").write_text(RIG.format(interface=emu))
        with RigProcess(tmp_path / "rig.toml", workdir=tmp_path, timeout=60) as rig:
            done = subprocess.run(["ip", "netns", "exec", ns, sys.executable, str(tmp_path / "soem.py"), mst],
                                  capture_output=True, text=True, timeout=120, check=False)
            assert rig.proc.poll() is None, rig.log_text()[-2000:]
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result == [2, [AlState.SAFEOP, 0], [AlState.PREOP | ERR, 0x0001]]
