"""``gatewaylab sdo`` against `gatewaylab run`, as a user reads and writes a drive's objects from a shell:
expedited, segmented and block transfers (CiA 301 7.2.4.3), aborts with their code and text, an EDS for
names and types, and the exit codes of docs/cli.md (0 done, 1 the node refused or did not answer, 2 usage)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.cli.main import main
from gatewaylab.cli.sdo import TYPES, format_value, parse_value
from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
"""


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RigProcess]:
    folder = tmp_path_factory.mktemp("sdo")
    rig_file = folder / "rig.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, "--trace", f"can0={folder / 'can0.log'}", workdir=folder, timeout=60) as process:
        yield process


def sdo(rig: RigProcess, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "sdo", str(rig.ready_file), *args],
                          capture_output=True, text=True, timeout=120, check=False)


def trace_lines(rig: RigProcess) -> list[str]:
    return (Path(rig.ready_file).parent / "can0.log").read_text().splitlines()


def test_expedited_upload_prints_decimal_and_hex(rig: RigProcess) -> None:
    """0x1000 Device type (CiA 402 drive: 0x00020192, CiA 301 7.5.2.1) read in one expedited transfer."""
    out = sdo(rig, "2", "upload", "0x1000", "0", "--type", "u32")
    assert (out.returncode, out.stdout, out.stderr) == (0, "131474 (0x00020192)\n", "")


def test_segmented_upload_of_a_string_prints_text(rig: RigProcess) -> None:
    """0x1008 (VISIBLE_STRING, longer than 4 bytes) needs a segmented upload (CiA 301 7.2.4.3.5)."""
    out = sdo(rig, "2", "upload", "0x1008", "0", "--type", "str")
    assert out.returncode == 0, out.stderr
    assert out.stdout == "IDX 56 M CANopen (gatewaylab)\n"


def test_download_then_upload_back(rig: RigProcess) -> None:
    """0x1017 Producer heartbeat time (UNSIGNED16, rw): what is written reads back."""
    assert sdo(rig, "2", "download", "0x1017", "0", "750", "--type", "u16").returncode == 0
    out = sdo(rig, "2", "upload", "0x1017", "0", "--type", "u16")
    assert out.stdout == "750 (0x02EE)\n"
    assert sdo(rig, "2", "download", "0x1017", "0", "0", "--type", "u16").returncode == 0


def test_block_transfers_use_the_block_protocol(rig: RigProcess) -> None:
    """--block: the client initiates with ccs 6 (block download, 0xC_ first byte) and ccs 5 (block
    upload, 0xA_) as CiA 301 7.2.4.3.9/14 define; the values are the same as over segmented transfers."""
    before = len(trace_lines(rig))
    assert sdo(rig, "2", "download", "0x1017", "0", "300", "--type", "u16", "--block").returncode == 0
    out = sdo(rig, "2", "upload", "0x1008", "0", "--type", "str", "--block")
    assert (out.returncode, out.stdout) == (0, "IDX 56 M CANopen (gatewaylab)\n")
    assert sdo(rig, "2", "upload", "0x1017", "0", "--type", "u16").stdout == "300 (0x012C)\n"
    new = trace_lines(rig)[before:]
    requests = [line.split("#", 1)[1][:2] for line in new if " 602#" in line]
    assert requests, "no SDO request to node 2 in the trace"
    assert any(r.startswith("C") for r in requests), requests       # block download initiate
    assert any(r.startswith("A") for r in requests), requests       # block upload initiate
    sdo(rig, "2", "download", "0x1017", "0", "0", "--type", "u16")


def test_an_abort_prints_code_and_text_and_exits_1(rig: RigProcess) -> None:
    """A missing object: abort 0x06020000 "Object does not exist" (CiA 301 table 22); a read-only
    object written: 0x06010002."""
    out = sdo(rig, "2", "upload", "0x2000", "0")
    assert out.returncode == 1
    assert "SDO abort 0x06020000" in out.stderr and "not exist" in out.stderr
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr
    out = sdo(rig, "2", "download", "0x1008", "0", "x", "--type", "str")
    assert out.returncode == 1 and "SDO abort 0x06010002" in out.stderr


def test_a_node_that_does_not_answer_exits_1_with_one_line(rig: RigProcess) -> None:
    out = sdo(rig, "9", "upload", "0x1000", "0")
    assert out.returncode == 1
    assert out.stderr.count("\n") == 1 and "No SDO response" in out.stderr


def test_eds_gives_names_and_types(rig: RigProcess) -> None:
    """--eds: the drive's own EDS (its path is in the ready file) names objects and gives their types."""
    (node,) = json.loads(Path(rig.ready_file).read_text())["canopen"]["can0"].values()
    eds = node["eds"]
    out = sdo(rig, "2", "upload", "Identity object", "Vendor-ID", "--eds", eds)
    assert (out.returncode, out.stdout) == (0, "Vendor-ID: 251 (0x000000FB)\n")
    out = sdo(rig, "2", "upload", "0x1008", "0", "--eds", eds)
    assert out.stdout == "Manufacturer device name: IDX 56 M CANopen (gatewaylab)\n"
    assert sdo(rig, "2", "download", "Producer heartbeat time", "0", "250", "--eds", eds).returncode == 0
    assert sdo(rig, "2", "upload", "0x1017", "0", "--type", "u16").stdout == "250 (0x00FA)\n"
    sdo(rig, "2", "download", "0x1017", "0", "0", "--type", "u16")


@pytest.mark.parametrize("args", [
    ("2", "download", "0x1017", "0", "70000", "--type", "u16"),   # does not fit
    ("2", "download", "0x1017", "0", "5"),                         # no type
    ("200", "upload", "0x1000", "0"),                              # no such node-ID
    ("2", "upload", "0x1000x", "0"),                               # not a number
    ("2", "upload", "0x1000", "0", "5"),                           # a value for an upload
    ("2", "download", "0x2000", "0", "zz", "--type", "hex"),       # not hex
])
def test_usage_errors_exit_2_with_one_line(rig: RigProcess, args: tuple[str, ...],
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sdo", str(rig.ready_file), *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gatewaylab sdo: ") and err.count("\n") == 1


def test_a_missing_ready_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sdo", str(tmp_path / "nope.json"), "2", "upload", "0x1000", "0"]) == 2
    assert "no such ready file" in capsys.readouterr().err


@given(st.sampled_from(sorted(n for n, t in TYPES.items() if t.is_integer)), st.integers(-2**63, 2**64 - 1))
def test_integer_values_round_trip_or_are_refused(name: str, value: int) -> None:
    """Every integer a type holds is encoded little endian (CiA 301 7.1.4) and printed back as itself."""
    kind = TYPES[name]
    bits = 8 * kind.size
    low, high = (-(1 << bits - 1), (1 << bits - 1) - 1) if name.startswith("i") else (0, (1 << bits) - 1)
    if not low <= value <= high:
        with pytest.raises(Exception, match="does not fit"):
            parse_value(str(value), kind)
        return
    data = parse_value(str(value), kind)
    assert len(data) == kind.size and int.from_bytes(data, "little", signed=name.startswith("i")) == value
    assert format_value(data, kind).split(" ")[0] == str(value)


def test_values_of_other_lengths_print_as_hex_bytes() -> None:
    assert format_value(b"\x01\x02\x03", TYPES["u32"]) == "01 02 03"
    assert format_value(b"\xfb\x00\x00\x00", None) == "FB 00 00 00"
    assert parse_value("01:a2 ff", TYPES["hex"]) == b"\x01\xa2\xff"
