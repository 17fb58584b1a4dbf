"""The frame, working-counter and link faults through ``rig.faults`` on a simulated-clock rig, with the
in-process master (docs/faults.md "EtherCAT faults"): on the board while active, ended by their count,
their time or ``ec-clear``, and the ``gatewaylab fault`` command line that builds their requests.

ETG.1000.4: LRW counts +1 per slave that reads, +2 per slave that writes (working counter); a frame that
never returns is a lost frame to the master. ET1100 data sheet II 0x0807 bit 0: a SyncManager the PDI
deactivated locks its memory area, so the master's output write is refused and not counted.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gatewaylab.cli.fault import build_request
from gatewaylab.cli.main import build_parser
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[ethercat]
interface = "gl-none"
"""


@pytest.fixture
def rig(tmp_path: Path) -> Rig:
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    r = Rig.from_file(path)
    r.start()
    yield r  # type: ignore[misc]
    r.close()


def _master(rig: Rig) -> Master:
    segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
    master = Master(rig.clock, segment)
    master.bring_up()
    return master


def _board(rig: Rig) -> list[dict[str, object]]:
    faults: list[dict[str, object]] = rig.faults.ethercat_states()["faults"]
    return faults


def test_ec_lose_is_on_the_board_until_its_count_is_used_up(rig: Rig) -> None:
    """ec-lose 2 --cmd LRW: two process data cycles lost (the master counts them), the board shows the
    fault with what is left, then it is gone and the cycle's working counter is whole again."""
    m = _master(rig)
    full = m.exchange_process_data()
    answer = rig.faults.request({"fault": "ec-lose", "count": 2, "cmd": "LRW"})
    assert answer["fault"] == "ec-lose" and answer["left"] == 2 and answer["cmd"] == ["LRW"]
    assert [e["id"] for e in _board(rig)] == [answer["id"]]
    m.al_status(0)                                   # an FPRD passes
    lost = m.lost_frames
    assert m.exchange_process_data() == 0            # a lost cycle: WKC 0
    assert _board(rig)[0]["left"] == 1
    assert m.exchange_process_data() == 0
    assert m.lost_frames == lost + 2 and _board(rig) == []
    assert m.exchange_process_data() == full


def test_ec_wkc_through_the_in_process_backend(rig: Rig) -> None:
    """ec-wkc 1 -n 3: the in-process backend (InProcessBackend.from_rig, the rig's locked link) reads the
    working counter one too high for exactly three cycles."""
    backend = InProcessBackend.from_rig(rig)
    backend.master.bring_up()
    wkc, expected = backend.exchange()
    assert wkc == expected
    rig.faults.ec_wkc(1, count=3, cmd="LRW")
    assert [backend.exchange()[0] for _ in range(5)] == [expected + 1] * 3 + [expected] * 2
    assert _board(rig) == []


def test_ec_link_down_ends_by_itself(rig: Rig) -> None:
    """ec-link-down 0.5: nothing comes back for 0.5 s of the rig's clock, then the line answers again. No
    outputs reached the slaves meanwhile: their SM watchdog (100 ms) expired and they went to SAFEOP with
    the error flag and AL status code 0x001B (ETG.1000.6 'sync manager watchdog'); the master's
    re-initialisation (acknowledge, back to OP) brings the whole working counter back."""
    m = _master(rig)
    entry = rig.faults.ec_link_down(0.5)
    assert entry["ends_at"] == pytest.approx(rig.clock.now() + 0.5)
    with pytest.raises(TimeoutError_):
        m.al_status(1)
    rig.clock.advance(0.25)
    with pytest.raises(TimeoutError_):
        m.al_status(1)
    rig.clock.advance(0.3)
    assert _board(rig) == []
    states = rig.faults.ethercat_states()["devices"]
    assert {n: (d["state"], d["error"], d["code"]) for n, d in states.items()} == {
        "io-a": ("SAFEOP", True, 0x001B), "io-b": ("SAFEOP", True, 0x001B)}
    m.bring_up(ack_errors=True)
    assert m.exchange_process_data() == m.expected_wkc


def test_ec_delay_until_ec_clear(rig: Rig) -> None:
    """ec-delay without --seconds stays until ec-clear (the in-process master loses every delayed reply)."""
    m = _master(rig)
    answer = rig.faults.ec_delay(3000, jitter=500)
    assert answer["us"] == 3000 and answer["seed"] == 1 and "ends_at" not in answer
    lost = m.lost_frames
    assert [m.exchange_process_data() for _ in range(3)] == [0, 0, 0] and m.lost_frames == lost + 3
    cleared = rig.faults.ec_clear()
    assert [e["fault"] for e in cleared["ended"]] == ["ec-delay"]
    assert m.exchange_process_data() == m.expected_wkc


def test_ec_outputs_off_takes_the_outputs_out_of_the_working_counter(rig: Rig) -> None:
    """ec-outputs-off io-b: io-b's output SyncManager is deactivated (0x0807 bit 0), the LRW counts 2 less;
    io-b stays in OP; ec-clear io-b activates it again. With --seconds it ends by itself."""
    m = _master(rig)
    full = m.exchange_process_data()
    answer = rig.faults.ec_outputs_off("io-b")
    assert answer["target"] == "io-b" and answer["sm"] == 2
    assert m.exchange_process_data() == full - 2
    assert rig.faults.ethercat_states()["devices"]["io-b"]["state"] == "OP"
    with pytest.raises(FaultRefused):
        rig.faults.ec_outputs_off("io-b")
    rig.faults.ec_clear("io-b")
    assert m.exchange_process_data() == full
    # shorter than the SM watchdog (100 ms): outputs refused are not written, so a longer fault would take
    # io-a to SAFEOP with AL status code 0x001B, as a real slave
    rig.faults.ec_outputs_off("io-a", seconds=0.05)
    seen: list[int] = []
    m.start_cyclic(0.001, lambda master: seen.append(master.last_wkc))
    rig.clock.advance(0.06)
    m.stop_cyclic()
    assert set(seen) == {full - 2, full} and seen[-1] == full and _board(rig) == []
    assert rig.faults.ethercat_states()["devices"]["io-a"]["state"] == "OP"


def test_refusals(rig: Rig) -> None:
    """Counts below 1, a zero WKC offset, a bad range or command, an unknown device: refused, nothing armed."""
    for call in (lambda: rig.faults.ec_lose(0), lambda: rig.faults.ec_wkc(0),
                 lambda: rig.faults.ec_lose(1, logical="5:1"), lambda: rig.faults.ec_lose(1, cmd="LRX"),
                 lambda: rig.faults.ec_delay(-1), lambda: rig.faults.ec_link_down(0),
                 lambda: rig.faults.ec_outputs_off("nobody"),
                 lambda: rig.faults.request({"fault": "ec-lose", "replies": 1})):
        with pytest.raises(FaultRefused):
            call()
    assert _board(rig) == []


@pytest.mark.parametrize(("argv", "wanted"), [
    (["ec-lose", "3", "--replies", "--cmd", "lrw", "--cmd", "FPWR", "--station", "0x1001", "--logical", "0:0xFF"],
     {"fault": "ec-lose", "count": 3, "replies": True, "cmd": "LRW,FPWR", "station": 0x1001, "logical": "0:0xFF"}),
    (["ec-corrupt", "2"], {"fault": "ec-corrupt", "count": 2}),
    (["ec-delay", "3000", "--jitter", "250", "--seconds", "2", "--seed", "9"],
     {"fault": "ec-delay", "us": 3000.0, "jitter": 250.0, "seconds": 2.0, "seed": 9}),
    (["ec-duplicate", "1"], {"fault": "ec-duplicate", "count": 1}),
    (["ec-reorder", "4"], {"fault": "ec-reorder", "count": 4}),
    (["ec-wkc", "-1", "-n", "5", "--cmd", "LRW"], {"fault": "ec-wkc", "offset": -1, "count": 5, "cmd": "LRW"}),
    (["ec-outputs-off", "io1", "--seconds", "1"], {"fault": "ec-outputs-off", "device": "io1", "seconds": 1.0}),
    (["ec-link-down", "1.5"], {"fault": "ec-link-down", "seconds": 1.5}),
])
def test_cli_builds_the_requests(argv: list[str], wanted: dict[str, object]) -> None:
    """Each verb of `gatewaylab fault` sends the request of docs/faults.md."""
    args = build_parser().parse_args(["fault", "ready.json", *argv])
    assert build_request(args) == wanted
