"""One exit-code table across the commands (docs/cli.md, issue 25): 2 for usage errors and things not
found (bad option, missing ready file or trace, out-of-range argument), 1 when a device or the rig did not
answer or refused; always one line on stderr, never a traceback."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator
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


# --- one rule for every command (docs/cli.md, the table and "The rule behind the table"): 2 for what the
# user typed or wrote wrong or names something that is not there, 1 for what was there and failed in use.

BAD_ENDPOINT = "tcp:localhost:xx"


def _setup(tmp_path: Path) -> dict[str, str]:
    """Files the cases name: a folder, a file that is not a ready file, a small candump trace."""
    (tmp_path / "rdir").mkdir()
    (tmp_path / "notready.json").write_text("[]")
    (tmp_path / "t.log").write_text("(0.000000) can0 123#00\n(0.001000) can0 124#01\n")
    (tmp_path / "rig.toml").write_text('[[bus]]\nname = "can0"\n')
    return {"NOSOCK": str(tmp_path / "nodir" / "nope.sock")}


@pytest.mark.parametrize("args, says", [
    (("run", "nosuch.toml"), "cannot read rig file nosuch.toml"),
    (("run", "rig.toml", "--ready-file", "rdir"), "--ready-file rdir: is a folder"),
    (("run", "rig.toml", "--trace", "can0=nodir/x.log"), "--trace nodir/x.log: folder"),
    (("demo", "nosuch.toml"), "cannot read rig file nosuch.toml"),
    (("rig", "nosuch.toml"), "cannot read rig file nosuch.toml"),
    (("dump", BAD_ENDPOINT), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("monitor", BAD_ENDPOINT, "--plain"), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("send", BAD_ENDPOINT, "123#00"), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("lss", BAD_ENDPOINT, "inquire", "all"), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("idx", "read", BAD_ENDPOINT, "0", "0x1000", "0"), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("play", BAD_ENDPOINT, "t.log"), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("sdo", BAD_ENDPOINT, "2", "upload", "0x1000", "0"), "endpoint 'tcp:localhost:xx': port 'xx' is not a number"),
    (("play", "unix:NOSOCK", "t.log"), "unix:NOSOCK: no such socket"),
    (("sdo", "unix:NOSOCK", "2", "upload", "0x1000", "0"), "unix:NOSOCK: no such socket"),
    (("dump", "unix:NOSOCK"), "unix:NOSOCK: no such socket"),
    (("monitor", "unix:NOSOCK", "--plain"), "unix:NOSOCK: no such socket"),
    (("send", "unix:NOSOCK", "123#00"), "unix:NOSOCK: no such socket"),
    (("lss", "unix:NOSOCK", "inquire", "all"), "unix:NOSOCK: no such socket"),
    (("idx", "read", "NOSOCK", "0", "0x1000", "0"), "No such file or directory"),
    (("idx", "read", "unix:NOSOCK", "0", "0x1000", "0"), "an IDX has no Unix-socket port"),
    (("fault", "notready.json", "bus-off", "can0"), "notready.json: not the ready file of a rig"),
    (("fault", "rdir", "bus-off", "can0"), "cannot read ready file rdir"),
    (("monitor", "notready.json", "--plain"), "notready.json: the ready file lists no bus 'can0'"),
    (("lesson", "nosuch"), "invalid choice: 'nosuch'"),
    (("plot", "t.log", "-o", "nodir/x.png"), "No such file or directory (nodir/x.png)"),
    (("ec", "slaves", "--master", "NOSOCK"), "NOSOCK: no master serving there"),
    (("ecan", "pack", "nosuch.bin", "--version", "1.0", "--build", "1", "-o", "x.efw"), "cannot read nosuch.bin"),
    (("net", "down", "glnosuch0"), "no such network interface 'glnosuch0'"),
])
def test_every_command_exits_2_for_what_the_user_typed_wrong(tmp_path: Path, args: tuple[str, ...],
                                                             says: str) -> None:
    """docs/cli.md: a malformed endpoint, a path that is not there, a file that is not what it should be:
    exit 2 in every command alike (dump, monitor, send, lss and idx used to differ), one line."""
    if args[0] == "net" and os.geteuid() != 0:
        pytest.skip("gatewaylab net checks for CAP_NET_ADMIN before its arguments (exit 1 without it)")
    names = _setup(tmp_path)
    args = tuple(a.replace("NOSOCK", names["NOSOCK"]) for a in args)
    says = says.replace("NOSOCK", names["NOSOCK"])
    out = gl(*args, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert says in lines[-1] and "Traceback" not in out.stderr
    assert len(lines) == 1 or (len(lines) == 2 and lines[0].startswith("usage: ")), out.stderr   # argparse's


@pytest.fixture
def refusing_port() -> Iterator[int]:
    """A TCP port on 127.0.0.1 that is bound but not listening: connections are refused as long as the
    test holds it (nobody else can take it meanwhile)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        yield sock.getsockname()[1]


@pytest.mark.parametrize("args", [
    ("dump", "tcp:127.0.0.1:PORT"),
    ("monitor", "tcp:127.0.0.1:PORT", "--plain"),
    ("send", "tcp:127.0.0.1:PORT", "123#00"),
    ("lss", "tcp:127.0.0.1:PORT", "inquire", "all"),
    ("idx", "read", "tcp:127.0.0.1:PORT", "0", "0x1000", "0"),
    ("play", "tcp:127.0.0.1:PORT", "t.log"),
    ("sdo", "tcp:127.0.0.1:PORT", "2", "upload", "0x1000", "0"),
])
def test_every_client_exits_1_when_nobody_answers_at_an_endpoint(tmp_path: Path, refusing_port: int,
                                                                 args: tuple[str, ...]) -> None:
    """docs/cli.md: a well-formed endpoint where nobody accepts the connection failed at run time: 1."""
    _setup(tmp_path)
    out = gl(*(a.replace("PORT", str(refusing_port)) for a in args), cwd=tmp_path)
    assert out.returncode == 1, out.stderr
    assert "Connection refused" in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_a_port_in_use_is_1_on_the_command_line_as_in_the_rig_file(tmp_path: Path) -> None:
    """docs/cli.md: "a port in use at `run`, whether the rig file's tcp_port/socketcand_port or --web
    PORT" is 1 (`--web` used to exit 2 while tcp_port exited 1)."""
    (tmp_path / "rig.toml").write_text('[[bus]]\nname = "can0"\n')
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        (tmp_path / "tcp.toml").write_text(f'[[bus]]\nname = "can0"\nendpoint = "tcp"\ntcp_port = {port}\n')
        (tmp_path / "sc.toml").write_text(f'[[bus]]\nname = "can0"\nsocketcand = true\nsocketcand_port = {port}\n')
        outs = {"--web": gl("run", "rig.toml", "--web", str(port), cwd=tmp_path),
                "tcp_port": gl("run", "tcp.toml", cwd=tmp_path),
                "socketcand_port": gl("run", "sc.toml", cwd=tmp_path)}
    for what, out in outs.items():
        assert out.returncode == 1, (what, out.stderr)
        assert f"{what} {'= ' if what != '--web' else ''}{port} cannot be used on 127.0.0.1" in out.stderr
        assert len(out.stderr.strip().splitlines()) == 1 and "Traceback" not in out.stderr


def test_ready_file_that_is_a_folder_names_the_option_and_leaves_it(tmp_path: Path) -> None:
    """`run --ready-file DIR` said "Is a directory (rdir)" (exit 1) after starting the rig; now the option
    is named before anything starts (exit 2) and the folder is left as it was."""
    (tmp_path / "rig.toml").write_text('[[bus]]\nname = "can0"\n')
    (tmp_path / "rdir").mkdir()
    (tmp_path / "rdir" / "keep").write_text("x")
    out = gl("run", "rig.toml", "--ready-file", "rdir", cwd=tmp_path)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.strip() == ("gatewaylab: --ready-file rdir: is a folder; give the name of a file (in it, "
                                  "or elsewhere)")
    assert [p.name for p in (tmp_path / "rdir").iterdir()] == ["keep"]
