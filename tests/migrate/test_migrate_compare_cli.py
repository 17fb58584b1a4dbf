"""Issue 13 part 3: ``gatewaylab migrate compare --rig RIG.toml --bus can0 --app APP.py [--report DIR]``
runs the same application once through an esd gateway and once through an ECAN-Lite channel on
identical copies of the rig, in process on the simulated clock, and "must find the difference"
(issue 13 'Tests and benchmarks'); the examples run through it."""

from __future__ import annotations

import json
from pathlib import Path

import can
import pytest

from gatewaylab.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
RIG = """
[[bus]]
name = "can0"
bitrate = 500000

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
"""
#: reads 0x1000 of drive 2 by a raw expedited SDO upload, then lets 20 ms pass
SAME_APP = """
import can

def run(bus):
    bus.send(can.Message(arbitration_id=0x602, data=bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]), is_extended_id=False))
    while (msg := bus.recv(0.02)) is not None:
        pass
"""
#: the same, plus one extra frame when the bus is the ECAN-Lite's (its channel name says so)
DIFFERENT_APP = SAME_APP + """
    if "ecanlite" in bus.channel_info:
        bus.send(can.Message(arbitration_id=0x123, data=b"\\xaa", is_extended_id=False))
"""


@pytest.fixture
def rig(tmp_path: Path) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    return path


def _app(tmp_path: Path, text: str, name: str = "app.py") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _compare(rig: Path, app: Path, report: Path, *extra: str) -> int:
    return main(["migrate", "compare", "--rig", str(rig), "--bus", "can0", "--app", str(app),
                 "--report", str(report), *extra])


def test_identical_app_exits_0_with_a_report(rig: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 13 part 3: the same application through both gateways; identical CAN traffic -> exit 0,
    the one-line verdict on stdout, traces (python-can writers) and the Markdown/HTML report with
    plots in DIR; the same inputs give a byte-identical report (simulated clock, deterministic)."""
    app = _app(tmp_path, SAME_APP)
    report = tmp_path / "rep"
    assert _compare(rig, app, report) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("identical CAN traffic: ")
    for name in ("report.md", "report.html", "latency.png", "timeline.png", "esd.bus.csv", "ecanlite.bus.csv",
                 "esd.sent.csv", "ecanlite.received.csv"):
        assert (report / name).is_file(), name
    bus = list(can.LogReader(str(report / "esd.bus.csv")))
    assert [m.arbitration_id for m in bus][-2:] == [0x602, 0x582]      # (after the drive's boot-up)
    md = (report / "report.md").read_text()
    assert "**identical**" in md and "| esd CAN-EtherCAT | master -> CAN | 1 |" in md
    again = tmp_path / "rep2"
    assert _compare(rig, app, again) == 0
    for name in ("report.md", "report.html", "latency.png", "timeline.png", "esd.bus.csv"):
        assert (again / name).read_bytes() == (report / name).read_bytes(), name


def test_different_app_is_found_and_exits_1(rig: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 13 'migrate compare on ... deliberately different apps (it must find the difference)': an
    application that sends one more frame through the ECAN-Lite -> exit 1, the verdict and the
    report name the frame only in the ECAN-Lite's trace."""
    report = tmp_path / "rep"
    assert _compare(rig, _app(tmp_path, DIFFERENT_APP), report, "--json") == 1
    summary = json.loads(capsys.readouterr().out)
    assert summary["identical"] is False and summary["only"] == [0, 1]
    assert summary["latency"]["ECAN-Lite MCAN0"]["master_to_can"]["count"] == 2
    md = (report / "report.md").read_text()
    assert "Frames only through ECAN-Lite MCAN0 (1):" in md
    assert "123 [1] AA" in md
    assert "| 123 | 0 | 1 | 0 | 0 | application |" in md
    assert "123 [1] AA" in (report / "report.html").read_text()


@pytest.mark.parametrize(("rig_text", "app_text", "extra", "message"), [
    (RIG + '\n[[device]]\nkind = "esd_can_ethercat"\nname = "esd1"\nbus = "can0"\n', SAME_APP, (),
     "compare adds each gateway itself"),
    (RIG, "x = 1\n", (), "defines no run(bus)"),
    (RIG, SAME_APP, ("--seconds", "1"), "takes no seconds parameter"),
    (RIG.replace('"can0"', '"can7"'), SAME_APP, (), "no [[bus]] named 'can0'"),
])
def test_usage_errors_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], rig_text: str, app_text: str,
                             extra: tuple[str, ...], message: str) -> None:
    """Issue 13 part 3: 'RIG holds the buses and drives (no gateways); APP.py defines run(bus)': a rig
    with a gateway, an application without run(), --seconds for a run() without it, an unknown bus
    are usage errors (exit 2, one line naming the problem), nothing is run."""
    rig = tmp_path / "rig.toml"
    rig.write_text(rig_text)
    assert _compare(rig, _app(tmp_path, app_text), tmp_path / "rep", *extra) == 2
    assert message in capsys.readouterr().err


def test_failing_app_exits_3(rig: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 13 part 3 (exit status, docs/migration-esd-to-ecanlite.md): an application that raises
    is neither 'identical' nor 'different': exit 3, the error named."""
    app = _app(tmp_path, "def run(bus):\n    raise RuntimeError('drive not found')\n")
    assert _compare(rig, app, tmp_path / "rep") == 3
    assert "RuntimeError: drive not found" in capsys.readouterr().out


def test_sdo_pdo_example_is_identical(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 13 part 3 'Example apps in examples/: a CANopen SDO/PDO application' (python canopen:
    SDO reads/writes, PDO configuration, SYNC, TPDOs), short: the same CAN traffic through both."""
    report = tmp_path / "rep"
    assert _compare(EXAMPLES / "migrate_rig.toml", EXAMPLES / "migrate_sdo_pdo_app.py", report,
                    "--seconds", "0.03") == 0
    bus = list(can.LogReader(str(report / "esd.bus.csv")))
    assert sum(m.arbitration_id == 0x080 for m in bus) == 3                     # the SYNCs
    assert sum(m.arbitration_id == 0x182 for m in bus) == 3                     # TPDO1 answering each


def test_cia402_example_differs_only_in_what_the_drives_answer(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 13 part 3 'a CiA 402 CSP loop ... compared across the two gateways', short: every frame
    the application sends (NMT, SDO, RPDOs, SYNC) is the same through both gateways; what differs
    is the drives' actual positions in their TPDOs (the loop's period through each gateway differs,
    so the drives are elsewhere when SYNC samples them): exit 1, all differences 'other nodes'."""
    report = tmp_path / "rep"
    code = _compare(EXAMPLES / "migrate_rig.toml", EXAMPLES / "migrate_cia402_csp.py", report,
                    "--seconds", "0.05", "--json")
    summary = json.loads(capsys.readouterr().out)
    assert code == 1
    assert summary["only"] == [0, 0] and summary["order"] == 0 and summary["payload"] > 0
    md = (report / "report.md").read_text()
    rows = [line for line in md.splitlines() if line.startswith("| 18")]
    assert rows and all(line.endswith("| other nodes |") for line in rows)
    assert "| application |\n" not in md


def test_recv_lets_simulated_time_pass_on_the_starting_thread(tmp_path: Path) -> None:
    """Issue 13 part 3 'on the simulated clock (deterministic ... faster than real time)': an
    application's recv(timeout) with nothing queued lets `timeout` of simulated time pass (the
    EtherCAT cycles run) and returns None; a frame arriving meanwhile ends it early. Another
    thread's recv (a notifier's) does not run the simulation."""
    import threading

    rig = tmp_path / "esd.toml"
    rig.write_text(RIG + '\n[[device]]\nkind = "esd_can_ethercat"\nname = "esd1"\nbus = "can0"\n')
    bus = can.Bus(interface="esd_can_ethercat", channel=f"rig:{rig}", bitrate=500_000)
    try:
        clock = bus.host.clock      # type: ignore[attr-defined]
        while bus.recv(0.01) is not None:                # the drive's boot-up
            pass
        t0 = clock.now()
        assert bus.recv(0.25) is None
        assert clock.now() - t0 == pytest.approx(0.25)
        cycles = bus.host.cycles    # type: ignore[attr-defined]
        seen: list[can.Message | None] = []
        worker = threading.Thread(target=lambda: seen.append(bus.recv(0.01)))
        worker.start()
        worker.join()
        assert seen == [None] and bus.host.cycles == cycles   # type: ignore[attr-defined]
        bus.send(can.Message(arbitration_id=0x602, data=bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]),
                             is_extended_id=False))
        answer = bus.recv(1.0)
        assert answer is not None and answer.arbitration_id == 0x582
    finally:
        bus.shutdown()
