"""The command line and rig files (issue 2, section 4)."""

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.explain import explain
from gatewaylab.cli.main import build_parser, main
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.config import load_rig, parse_rig
from gatewaylab.rig.runtime import Rig


def _subcommands() -> list[str]:
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return sorted(action.choices)  # type: ignore[union-attr]


def test_top_level_help_lists_every_subcommand() -> None:
    """`gatewaylab --help` is complete: every sub-command is listed (issue 2 §4)."""
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "--help"], capture_output=True, text=True,
                         check=True).stdout
    for name in _subcommands():
        assert name in out
    assert "run" in _subcommands() and "demo" in _subcommands()


@pytest.mark.parametrize("name", _subcommands())
def test_every_subcommand_has_complete_help(name: str, capsys) -> None:
    """Every sub-command's help is complete (issue 2 §4)."""
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert f"gatewaylab {name}" in out and len(out.splitlines()) >= 4


def test_run_help_documents_ready_file_and_trace(capsys) -> None:
    """`gatewaylab run --help` documents --ready-file, --trace BUS=FILE and the signals (issue 2 §4)."""
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    out = capsys.readouterr().out
    assert "--ready-file" in out and "--trace" in out and "BUS=FILE" in out and "SIGTERM" in out


def test_default_rig_is_shipped_and_valid() -> None:
    """Without a rig argument the default rig shipped in the package runs (issue 2 §4)."""
    cfg = load_rig(None)
    assert cfg.buses and cfg.buses[0].name == "can0"


@pytest.mark.parametrize("data, message", [
    ({"bus": [{"name": "can0", "bitrate": 2_000_000}]}, "bitrate"),
    ({"bus": [{"name": "can0"}, {"name": "can0"}]}, "unique"),
    ({"bus": [{"name": "can0", "colour": "red"}]}, "unknown keys"),
    ({"bus": [{"name": "can0"}], "drive": [{"bus": "can9"}]}, "unknown bus"),
    ({"bus": [{"name": "can0"}], "device": [{"bus": "can0"}]}, "needs a kind"),
    ({"clock": "sundial"}, "clock must be"),
    ({"bus": [{"name": "can0", "bitrate": 500_000, "data_bitrate": 100_000}]}, "data_bitrate"),
])
def test_bad_rig_files_are_refused_with_a_clear_message(data: dict, message: str) -> None:
    """A rig file that describes something impossible is refused with a ConfigError naming it (docs/rig.md)."""
    with pytest.raises(ConfigError, match=message):
        parse_rig(data)


def test_run_reports_a_bad_rig_file_and_exits_nonzero(tmp_path: Path, capsys) -> None:
    """`gatewaylab run` reports a bad rig file on stderr and exits non-zero, no traceback (docs/rig.md);
    issue 15 "Errors a user can act on": a config error exits 2 (usage), runtime failures 1."""
    rig = tmp_path / "bad.toml"
    rig.write_text("[[bus]]\nname = 'can0'\nbitrate = 'fast'\n")
    assert main(["run", str(rig)]) == 2
    assert "bitrate" in capsys.readouterr().err


def test_simulated_rig_from_python() -> None:
    """A rig file with clock = 'simulated' builds buses on a SimulatedClock from Python (issue 2 §4, docs/rig.md)."""
    rig = Rig(parse_rig({"clock": "simulated", "bus": [{"name": "a"}, {"name": "b", "bitrate": 250_000}]}))
    try:
        assert isinstance(rig.clock, SimulatedClock) and not rig.servers
        got: list[CanFrame] = []
        rig.buses["b"].attach("rx", on_frame=lambda f, t: got.append(f))
        rig.buses["b"].attach("tx").send(CanFrame(0x80))
        rig.clock.advance(0.01)
        assert got == [CanFrame(0x80)]
    finally:
        rig.close()


@pytest.mark.parametrize("frame, meaning", [
    (CanFrame(0x000, b"\x01\x00"), "NMT start (-> Operational) to all nodes"),
    (CanFrame(0x000, b"\x82\x05"), "NMT reset communication to node 5"),
    (CanFrame(0x705, b"\x00"), "boot-up of node 5"),
    (CanFrame(0x705, b"\x7f"), "heartbeat of node 5: Pre-operational"),
    (CanFrame(0x605, bytes.fromhex("4018100100000000")), "SDO initiate upload 0x1018:01 to node 5"),
    (CanFrame(0x585, bytes.fromhex("8000100000000206")),
     "SDO abort 0x1000:00 code 0x06020000 from node 5"),
    (CanFrame(0x7E5, bytes([0x5E]) + bytes(7)), "LSS master: inquire node id"),
    (CanFrame(0x185, b"\x37\x02"), "TPDO1 from node 5"),
])
def test_explainer_names_canopen_frames(frame: CanFrame, meaning: str) -> None:
    """CiA 301 predefined connection set / CiA 305 LSS ids, as a student would read them."""
    assert meaning in explain(frame)


def test_a_failing_callback_is_logged_and_the_realtime_rig_keeps_running(caplog) -> None:
    """Bad input never stops the emulator (DEVELOPERS.md, principle 4): the loop logs and carries on."""
    from gatewaylab.common.clock import RealTimeClock

    rig = Rig(parse_rig({"bus": [{"name": "can0", "endpoint": "none"}]}), clock=RealTimeClock())
    done: list[bool] = []

    def boom() -> None:
        raise RuntimeError("participant bug")

    try:
        rig.clock.call_soon(boom)
        rig.clock.call_later(0.001, done.append, True)
        rig.run(until=lambda: bool(done))
        assert done == [True] and rig.callback_errors == 1
        assert "participant bug" in caplog.text
    finally:
        rig.close()


def test_make_demo_runs_on_the_default_rig_and_explains_real_traffic() -> None:
    """`make demo` (issue 2 §4): real traffic on the default rig, explained, exits by itself."""
    out = subprocess.run([sys.executable, "-m", "gatewaylab.cli.demo"], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert "NMT reset communication to all nodes" in out
    assert "boot-up of node 2" in out and "boot-up of node 4" in out          # 4: assigned by LSS Fastscan
    assert "serial 0x1004" in out and "LSS slave: configure node id answer, error code 0" in out
    assert "target reached: True), position actual 1000" in out
    assert "ReadObject 0x6064 of node 2 through the IDX's SDO gateway: 1000" in out
