"""One exit-code table across the commands (docs/cli.md, issue 25): 2 for usage errors and things not
found (bad option, missing ready file or trace, out-of-range argument), 1 when a device or the rig did not
answer or refused; always one line on stderr, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.rig.process import RigProcess


def gl(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


@pytest.mark.parametrize("args, code, says", [
    (("run", "--web", "99999"), 2, "--web wants a TCP port 0..65535"),
    (("run", "--web", "http"), 2, "--web wants a TCP port"),
    (("fault", "nosuch.json", "bus-off", "axis2"), 2, "nosuch.json: no such ready file"),
    (("monitor", "nosuch.json", "--plain"), 2, "nosuch.json: no such ready file"),
    (("dump", "nosuch.json"), 2, "nosuch.json: no such ready file"),
    (("send", "nosuch.json", "123#00"), 2, "nosuch.json: no such ready file"),
    (("lss", "nosuch.json", "inquire", "all"), 2, "nosuch.json: no such ready file"),
    (("monitor", "--replay", "nosuch.asc"), 2, "nosuch.asc: no such trace file"),
    (("plot", "nosuch.asc"), 2, "nosuch.asc: no such trace file"),
    (("dump", "x.json", "-f", "12G:7FF"), 2, "filter '12G:7FF'"),
    (("lss", "x.json", "set-node-id", "200"), 2, "node-ID must be 1..127 or 0xFF"),
    (("lss", "x.json", "set-node-id", "0"), 2, "node-ID must be 1..127 or 0xFF"),
    # an interface that does not exist is not found, not a matter of permissions (issue 25)
    (("ec", "slaves", "-i", "nosuchif0"), 2, "no such network interface 'nosuchif0'"),
    # migrate config names the file it could not use (issue 25)
    (("migrate", "config", "nosuch.xml", "-o", "out.xml"), 2, "nosuch.xml: cannot read it"),
])
def test_usage_and_not_found_exit_2_with_one_clear_line(tmp_path: Path, args: tuple[str, ...], code: int,
                                                         says: str) -> None:
    out = gl(*args, cwd=tmp_path)
    assert out.returncode == code, out.stderr
    assert says in out.stderr and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].count(says) == 1


def test_lss_set_node_id_without_a_selected_slave_says_what_to_do(tmp_path: Path) -> None:
    """CiA 305 8.3.2.1: configure node-ID is answered only by the slave in configuration state; with none
    selected nobody answers: exit 1 (the device did not answer) and the services that select one."""
    with RigProcess(None, workdir=tmp_path, timeout=60) as rig:
        out = gl("lss", str(rig.ready_file), "set-node-id", "5")
    assert out.returncode == 1
    err = out.stderr.strip()
    assert "no slave in LSS configuration state answered" in err and "switch-selective" in err and "fastscan" in err
    assert "\n" not in err and "Traceback" not in err


@pytest.mark.parametrize("name, text, says", [
    ("bad.xml", "<EtherCATConfig><bad", "bad.xml: not XML"),
    ("writes.txt", "garbage = [\n", "writes.txt: line 1: expected 'INDEX:SUB TYPE VALUE [ca]'"),
])
def test_migrate_config_errors_name_the_file(tmp_path: Path, name: str, text: str, says: str) -> None:
    """docs/cli.md: a file the command cannot use is one line naming the file (and the line in it), exit 2."""
    (tmp_path / name).write_text(text)
    out = gl("migrate", "config", name, "-o", "out.xml", cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert says in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
