"""`gatewaylab run` with a maxon_idx device and the `gatewaylab idx ...` commands (issue 4 CLI)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from maxon_helpers import IdxRig

from gatewaylab.cli.main import main
from gatewaylab.hosts.maxon_idx.client import IdxClient, IdxValueError

RIG_FILE = """\
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
endpoint = "none"
[[device]]
kind = "maxon_idx"
name = "idx1"
bus = "can0"
node_id = 1
serial = 0x2001
usb = { pty = true, tcp_port = 0 }
"""


def test_run_ready_file_and_idx_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 4: `gatewaylab run --ready-file` adds "usb": {"idx1": {"pty", "tcp"}}; `gatewaylab idx read/
    write/nmt` work against that port (ReadObject 2.1.1.1, WriteObject 2.1.2.1, SendNMTService 2.1.2.4)."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG_FILE)
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen([sys.executable, "-m", "gatewaylab.cli.main", "run", str(rig_file),
                             "--ready-file", str(ready)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if "running" in line:
                break
        info = json.loads(ready.read_text())
        usb = info["usb"]["idx1"]
        assert usb["pty"].startswith("/dev/pts/") and usb["tcp"].startswith("tcp:127.0.0.1:")
        assert main(["idx", "read", usb["pty"], "0", "0x1018", "4"]) == 0
        assert "node 0 0x1018:04 = 8193 (0x00002001)" in capsys.readouterr().out
        assert main(["idx", "write", usb["tcp"], "1", "0x30B0", "0", "-5", "--type", "i32"]) == 0
        assert main(["idx", "read", usb["pty"], "1", "0x30B0", "0", "-t", "i32"]) == 0
        assert "= -5 (0xFFFFFFFB)" in capsys.readouterr().out
        assert main(["idx", "read", usb["pty"], "0", "0x1008", "0", "-t", "str"]) == 0
        assert "IDX" in capsys.readouterr().out
        assert main(["idx", "read", usb["pty"], "0", "0x7000", "0"]) == 1
        assert 'read node 0 0x7000:00: 0x06020000 "Object does not exist error"' in capsys.readouterr().err
        assert main(["idx", "nmt", usb["pty"], "5", "start"]) == 0
        assert "NMT start (1) sent to node 5" in capsys.readouterr().out
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
    assert proc.returncode == 0
    assert not ready.exists()


def test_lss_scan_assigns_node_id(capsys: pytest.CaptureFixture[str]) -> None:
    """`gatewaylab idx lss-scan --assign 7`: fastscan via SendLSS/ReadLSS (2.1.3), configure node id
    (3.5.2.3), back to waiting; the drive then answers SDO as node 7."""
    r = IdxRig([(None, 0x3003)])
    try:
        pty = r.info["usb"]["idx1"]["pty"]
        assert main(["idx", "lss-scan", pty]) == 0                     # find only, configure nothing
        out = capsys.readouterr().out
        assert "vendor 0x000000FB" in out and "serial 0x00003003" in out and "--assign N" in out
        assert main(["idx", "lss-scan", pty, "--assign", "7"]) == 0
        out = capsys.readouterr().out
        assert "serial 0x00003003 -> node id 7" in out
        assert main(["idx", "read", pty, "7", "0x1018", "4"]) == 0   # queued behind the LSS frames
        assert "= 12291 (0x00003003)" in capsys.readouterr().out
        with r.rig.clock.lock:
            assert r.drives[0].node.node_id == 7
        assert main(["idx", "lss-scan", pty]) == 0
        assert "no unconfigured LSS slave answered" in capsys.readouterr().out
    finally:
        r.close()


def test_cli_errors_are_clear(capsys: pytest.CaptureFixture[str]) -> None:
    """Chapter 6 names in the CLI: a missing node prints 0x05040000 "SDO timeout"; a port that does
    not exist, an index that does not fit the WORD of 2.1.1.1 and a value that does not fit its type
    are one-line errors, not tracebacks."""
    r = IdxRig([])
    try:
        pty = r.info["usb"]["idx1"]["pty"]
        assert main(["idx", "read", pty, "9", "0x1000", "0"]) == 1
        err = capsys.readouterr().err
        assert err.startswith("error: read node 9 0x1000:00: ") and '0x05040000 "SDO timeout"' in err
        # docs/cli.md: a serial device that does not exist is the user's to fix (2); a refused connection 1
        assert main(["idx", "read", "/dev/pts/nonexistent", "0", "0x1000", "0"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: cannot open port /dev/pts/nonexistent") and "Traceback" not in err
        assert main(["idx", "read", "socket://127.0.0.1:1", "0", "0x1000", "0"]) == 1
        assert "cannot open port socket://127.0.0.1:1" in capsys.readouterr().err
        for argv, message in ((["0", "0x10000", "0"], "index 0x10000 outside 0x0000..0xFFFF"),
                              (["0", "0x1000", "256"], "subindex 256 outside 0..255"),
                              (["128", "0x1000", "0"], "node id 128 outside 0..127"),
                              (["0", "x", "0"], "index 'x' is not a number")):
            with pytest.raises(SystemExit) as stop:
                main(["idx", "read", pty, *argv])
            assert stop.value.code == 2 and message in capsys.readouterr().err
        assert main(["idx", "write", pty, "0", "0x6040", "0", "70000", "-t", "u16"]) == 2
        assert "VALUE 70000 does not fit u16 (0..65535)" in capsys.readouterr().err
        assert main(["idx", "read", pty, "0", "0x1008", "0"]) == 1      # a string via ReadObject
        err = capsys.readouterr().err
        assert '0x06070010 "Service parameter error"' in err and "add -s or -t str" in err
    finally:
        r.close()


def test_idx_accepts_every_endpoint_form_of_the_ready_file(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 15, one endpoint syntax: the ready file's TCP port as printed (canonical tcp:127.0.0.1:PORT),
    the bare 127.0.0.1:PORT and pyserial's socket:// URL all reach the IDX (ReadObject 2.1.1.1)."""
    r = IdxRig([])
    try:
        printed = r.info["usb"]["idx1"]["tcp"]
        assert printed.startswith("tcp:")
        hostport = printed.removeprefix("tcp:")
        for port in (printed, hostport, "socket://" + hostport):
            assert main(["idx", "read", port, "0", "0x1018", "4"]) == 0
            assert "= 8193 (0x00002001)" in capsys.readouterr().out
            with IdxClient(port) as client:
                assert client.read(0, 0x1018, 4) == 0x2001
    finally:
        r.close()


def test_typed_read_refuses_a_value_that_does_not_fit(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 15: `idx read ... -t i16` of a value that does not fit reports an error (exit 2) instead of
    truncating. ReadObject (2.1.1.1) carries 4 bytes; 0x1018:04 = 0x2001 does not fit u8 or i8."""
    r = IdxRig([])
    try:
        pty = r.info["usb"]["idx1"]["pty"]
        for type_ in ("u8", "i8"):
            assert main(["idx", "read", pty, "0", "0x1018", "4", "-t", type_]) == 2
            err = capsys.readouterr().err
            assert f"the value 0x00002001 does not fit {type_}" in err and "Traceback" not in err
        assert main(["idx", "read", pty, "0", "0x1018", "4", "-t", "i16"]) == 0
        assert "= 8193 (0x2001)" in capsys.readouterr().out
        assert main(["idx", "write", pty, "1", "0x30B0", "0", "-5", "-t", "i32"]) == 0
        assert main(["idx", "read", pty, "1", "0x30B0", "0", "-t", "i16"]) == 0   # sign extension fits
        assert "= -5 (0xFFFB)" in capsys.readouterr().out
        with IdxClient(pty) as client, pytest.raises(IdxValueError):
            client.read(0, 0x1018, 4, "u8")
    finally:
        r.close()
