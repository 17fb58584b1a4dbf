"""Errors a user can act on (issue 15): one line on stderr, no traceback, exit 2 for a wrong command
line or rig file, exit 1 for a runtime failure. Every case runs the real `gatewaylab` command."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

RIG = """\
[[bus]]
name = "can0"
endpoint = "none"
"""


def gatewaylab(*args: str, user: str | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "gatewaylab", *args]
    if user == "nobody":
        cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--inh-caps=-all", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def assert_error(result: subprocess.CompletedProcess[str], code: int, *needles: str) -> str:
    """Exit ``code``, exactly one line on stderr containing every needle, no traceback."""
    err = result.stderr
    assert "Traceback" not in err, err
    assert result.returncode == code, (result.returncode, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


@pytest.fixture
def rig_file(tmp_path: Path) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    return path


@pytest.fixture
def nobody_dir() -> Iterator[Path]:
    """A folder the unprivileged user can enter (pytest's tmp_path is root's only)."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv to run a command as an unprivileged user")
    path = Path(tempfile.mkdtemp(prefix="gl-test-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path)


def test_missing_rig_file(tmp_path: Path) -> None:
    """A rig file that does not exist: usage error, names the file and the reason."""
    missing = tmp_path / "nope.toml"
    assert_error(gatewaylab("run", str(missing)), 2, f"cannot read rig file {missing}", "No such file")


def test_rig_and_demo_with_a_missing_rig_file(tmp_path: Path) -> None:
    """`gatewaylab rig FILE` and `gatewaylab demo FILE` report a missing file like `run` does."""
    missing = tmp_path / "nope.toml"
    assert_error(gatewaylab("rig", str(missing)), 2, f"cannot read rig file {missing}")
    assert_error(gatewaylab("demo", str(missing)), 2, "cannot read rig file")


def test_rig_file_is_a_directory_or_not_text(tmp_path: Path) -> None:
    """A folder or a binary file given as rig file: usage errors, no UnicodeDecodeError traceback."""
    assert_error(gatewaylab("run", str(tmp_path)), 2, "is a directory")
    binary = tmp_path / "rig.toml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    assert_error(gatewaylab("run", str(binary)), 2, "not UTF-8")


def test_unreadable_rig_file(nobody_dir: Path) -> None:
    """A rig file the user may not read: usage error saying so."""
    path = nobody_dir / "rig.toml"
    path.write_text(RIG)
    path.chmod(0o000)
    assert_error(gatewaylab("run", str(path), user="nobody"), 2, "cannot read rig file", "Permission denied")


def test_bad_rig_file_content_exits_2(tmp_path: Path) -> None:
    """Invalid TOML and impossible values are config errors: exit 2, one line naming the file."""
    bad = tmp_path / "bad.toml"
    bad.write_text("[[bus]\nname = \n")
    assert_error(gatewaylab("run", str(bad)), 2, str(bad))
    bad.write_text("[[bus]]\nname = 'can0'\nbitrate = 'fast'\n")
    assert_error(gatewaylab("run", str(bad)), 2, "bitrate")


def test_unsupported_trace_format_names_the_supported_ones(rig_file: Path, tmp_path: Path) -> None:
    """`--trace` with a suffix no writer streams: usage error listing the formats, pcap among them."""
    line = assert_error(gatewaylab("run", str(rig_file), "--trace", f"can0={tmp_path / 'x.mf4'}"), 2,
                        "'.mf4' is not supported", "supported:")
    for suffix in (".log", ".asc", ".blf", ".csv", ".trc", ".pcap", ".pcapng"):
        assert suffix in line
    assert_error(gatewaylab("run", str(rig_file), "--trace", f"can0={tmp_path / 'x'}"), 2, "no suffix")


def test_trace_into_a_missing_folder_or_of_an_unknown_bus(rig_file: Path, tmp_path: Path) -> None:
    """The trace's folder must exist; the bus must be one of the rig's."""
    assert_error(gatewaylab("run", str(rig_file), "--trace", f"can0={tmp_path / 'no' / 'x.log'}"), 2,
                 "--trace", "does not exist")
    assert_error(gatewaylab("run", str(rig_file), "--trace", f"can7={tmp_path / 'x.log'}"), 2, "can7")
    result = gatewaylab("run", str(rig_file), "--trace", "can0")     # argparse: usage line + error
    assert result.returncode == 2 and "BUS=FILE" in result.stderr and "Traceback" not in result.stderr


def test_ready_file_in_a_missing_folder(rig_file: Path, tmp_path: Path) -> None:
    """`--ready-file` in a folder that does not exist: usage error before anything starts."""
    assert_error(gatewaylab("run", str(rig_file), "--ready-file", str(tmp_path / "no" / "ready.json")), 2,
                 "--ready-file", "does not exist")


def test_port_in_use_is_a_runtime_failure(tmp_path: Path) -> None:
    """A bus endpoint whose TCP port is taken: exit 1, the OS's reason, no traceback."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rig = tmp_path / "tcp.toml"
        rig.write_text(f"[[bus]]\nname = 'can0'\nendpoint = 'tcp'\ntcp_port = {port}\n")
        assert_error(gatewaylab("run", str(rig)), 1, "in use")


def test_net_without_rights_says_which(nobody_dir: Path) -> None:
    """`gatewaylab net up` as an ordinary user: names root or CAP_NET_ADMIN, creates nothing."""
    line = assert_error(gatewaylab("net", "up", "gl-test0", user="nobody"), 1, "root or CAP_NET_ADMIN")
    assert "sudo" in line


def test_net_help_is_plain_text() -> None:
    """`gatewaylab net --help` prints plain text, no reStructuredText markup."""
    result = gatewaylab("net", "--help")
    assert result.returncode == 0
    assert "``" not in result.stdout and ":class:" not in result.stdout
    assert "CAP_NET_ADMIN" in result.stdout and "NAME-m" in result.stdout


def test_idx_on_something_that_is_not_a_serial_port() -> None:
    """`gatewaylab idx` on /dev/null: runtime failure "not a serial port", no traceback."""
    assert_error(gatewaylab("idx", "read", "/dev/null", "0", "0x1000", "0"), 1,
                 "cannot open port /dev/null", "not a serial port")


def test_idx_on_a_serial_port_without_an_idx() -> None:
    """A serial port where nothing answers (a pty nobody serves): says no IDX replied, exit 1."""
    master, slave = os.openpty()
    try:
        line = assert_error(gatewaylab("idx", "read", os.ttyname(slave), "0", "0x1000", "0", "--timeout", "0.3"),
                            1, "no reply from", "is it an IDX")
        assert "0x1000:00" in line
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("port, needle", [
    ("tcp:127.0.0.1:http", "is not a number"),
    ("tcp:127.0.0.1:70000", "outside 1..65535"),
    ("usb:xyz", "usb:VID:PID"),
])
def test_idx_bad_endpoint_is_a_usage_error(port: str, needle: str) -> None:
    """An endpoint that is no endpoint at all (docs/endpoints.md): exit 2 with what is wrong."""
    assert_error(gatewaylab("idx", "read", port, "0", "0x1000", "0"), 2, needle)


def test_idx_numbers_out_of_range_are_usage_errors() -> None:
    """Node id, index, subindex: decimal or 0x hex, range named in the message (argparse: exit 2)."""
    result = gatewaylab("idx", "read", "/dev/null", "0x80", "0x1000", "0")
    assert result.returncode == 2 and "node id 0x80 outside 0..127" in result.stderr
    assert "Traceback" not in result.stderr
