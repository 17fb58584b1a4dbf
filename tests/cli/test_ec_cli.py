"""``gatewaylab ec``: every verb against two ``ethercat_io`` slaves, in process (``--rig``) and,
with root, through SOEM on a veth pair (``-i``) in a test-made network namespace.

The expected output shapes are those of IgH's ``ethercat`` tool (``ethercat slaves``: position,
alias:position, state, flag, name; ``upload``: the value, integers as ``0x.. decimal``;
``sdos``/``pdos`` listings); errors are one stderr line, exit 1 when the slave refused, 2 for a
wrong command line.
"""

from __future__ import annotations

import io
import struct
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import pytest

from gatewaylab.cli.ec import TYPES, format_value, parse_value, state_path
from gatewaylab.cli.main import main as cli_main
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import VENDOR_ID, create_io_slave
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

RIG = """clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
revision = 2
[ethercat]
interface = "gl-none"
"""

PDOS_0 = """\
SM0: PhysAddr 0x1000, DefaultSize  128, ControlRegister 0x26, Enable 1
SM1: PhysAddr 0x1080, DefaultSize  128, ControlRegister 0x22, Enable 1
SM2: PhysAddr 0x1100, DefaultSize    5, ControlRegister 0x64, Enable 1
  RxPDO 0x1600 "Outputs"
    PDO entry 0x7000:01,  8 bit, "Digital outputs"
    PDO entry 0x7010:01, 16 bit, "Analog output 1"
    PDO entry 0x7010:02, 16 bit, "Analog output 2"
SM3: PhysAddr 0x1400, DefaultSize    9, ControlRegister 0x20, Enable 1
  TxPDO 0x1a00 "Inputs"
    PDO entry 0x6000:01,  8 bit, "Digital inputs"
    PDO entry 0x6010:01, 16 bit, "Analog input 1"
    PDO entry 0x6010:02, 16 bit, "Analog input 2"
    PDO entry 0x6020:01, 32 bit, "Cycle counter"
"""


@dataclass(frozen=True)
class Result:
    rc: int
    out: bytes
    err: str

    @property
    def text(self) -> str:
        return self.out.decode()


class Ec(Protocol):
    kind: str

    def __call__(self, verb: str, *args: str, stdin: bytes | None = None) -> Result: ...


class InProcessEc:
    """``gatewaylab ec VERB --rig RIG ...`` through the command line's main() in this process."""

    kind = "inprocess"

    def __init__(self, rig: Path, capsysbinary: pytest.CaptureFixture[bytes]) -> None:
        self.rig = rig
        self.cap = capsysbinary

    def __call__(self, verb: str, *args: str, stdin: bytes | None = None) -> Result:
        self.cap.readouterr()
        saved = sys.stdin
        if stdin is not None:
            sys.stdin = io.TextIOWrapper(io.BytesIO(stdin))
        try:
            rc = cli_main(["ec", verb, "--rig", str(self.rig), *args])
        except SystemExit as exc:      # argparse's usage errors, as the console script would exit
            rc = int(exc.code or 0)
        finally:
            sys.stdin = saved
        out, err = self.cap.readouterr()
        return Result(rc, out, err.decode())


class PysoemEc:
    """``gatewaylab ec VERB -i IFNAME ...`` as a process inside the namespace (SOEM through pysoem)."""

    kind = "pysoem"

    def __init__(self, veth: Any, segment: Segment) -> None:
        self.veth = veth
        self.segment = segment

    def __call__(self, verb: str, *args: str, stdin: bytes | None = None) -> Result:
        proc = subprocess.run(["ip", "netns", "exec", self.veth.namespace, sys.executable, "-m", "gatewaylab.cli.main",
                               "ec", verb, "-i", self.veth.master_iface, *args], input=stdin, capture_output=True,
                              timeout=120, check=False)
        return Result(proc.returncode, proc.stdout, proc.stderr.decode())


@pytest.fixture(scope="module")
def wire_segment(veth_ns: Any) -> Iterator[Segment]:
    """The same two slaves as RIG, answering on the emulator end of the veth pair."""
    clock = RealTimeClock()
    segment = Segment([create_io_slave(clock, "io-a"), create_io_slave(clock, "io-b", serial=7, revision=2)])
    wire = WireTransport(segment, veth_ns.emulator_iface, clock, drive_clock=True)
    wire.start()
    try:
        yield segment
    finally:
        wire.stop()


@pytest.fixture(params=["inprocess", pytest.param("pysoem", marks=[pytest.mark.net, pytest.mark.slow])])
def ec(request: pytest.FixtureRequest, tmp_path: Path, capsysbinary: pytest.CaptureFixture[bytes]) -> Ec:
    if request.param == "inprocess":
        rig = tmp_path / "rig.toml"
        rig.write_text(RIG)
        return InProcessEc(rig, capsysbinary)
    return PysoemEc(request.getfixturevalue("veth_ns"), request.getfixturevalue("wire_segment"))


def _ok(r: Result) -> Result:
    assert r.rc == 0, r.err
    assert r.err == "" or r.err.strip().startswith("foe "), r.err
    return r


def _fails(r: Result, rc: int, *fragments: str) -> None:
    """One line on stderr naming the problem, no traceback."""
    assert r.rc == rc, (r.rc, r.err)
    assert r.err.count("\n") == 1 and "Traceback" not in r.err, r.err
    assert r.err.startswith("gatewaylab ec"), r.err
    for f in fragments:
        assert f in r.err, r.err


# ------------------------------------------------------------------ verbs
def test_slaves_one_line_per_slave(ec: Ec) -> None:
    """IgH `ethercat slaves`: 'POSITION  ALIAS:POSITION  STATE  FLAG  NAME'; the line is in PREOP."""
    assert _ok(ec("slaves")).text == "0  0:0  PREOP  +  io-a\n1  0:1  PREOP  +  io-b\n"
    assert _ok(ec("slaves", "-p", "1")).text == "1  0:1  PREOP  +  io-b\n"


def test_slaves_verbose_identity(ec: Ec) -> None:
    """IgH `ethercat slaves -v`: identity block (vendor id, product code, revision, serial)."""
    text = _ok(ec("slaves", "-v", "-p", "1")).text
    assert text.startswith("=== Master 0, Slave 1 ===\n")
    assert f"  Vendor Id:       0x{VENDOR_ID:08x}\n" in text
    assert "  Revision number: 0x00000002\n" in text and "  Serial number:   0x00000007\n" in text


def test_states_list_and_request(ec: Ec) -> None:
    """`states` lists state, flag and AL status code; `states STATE` walks the ESM to it
    (ETG.1000.6: upwards one state at a time) and lists the result."""
    assert _ok(ec("states")).text == "0  PREOP   +  0x0000 NO_ERROR\n1  PREOP   +  0x0000 NO_ERROR\n"
    assert _ok(ec("states", "-p", "1", "safeop")).text == "1  SAFEOP  +  0x0000 NO_ERROR\n"
    assert _ok(ec("states", "-p", "0", "INIT")).text == "0  INIT    +  0x0000 NO_ERROR\n"


def test_states_refused_names_the_al_status_code(ec: Ec) -> None:
    """BOOT without a bootstrap mailbox: AL status code 0x0013 by name, exit 1."""
    _fails(ec("states", "-p", "0", "BOOT"), 1, "0x0013 BOOTSTRAP_NOT_SUPPORTED")


def test_upload_prints_just_the_value(ec: Ec) -> None:
    """IgH `ethercat upload --type string 0x1008 0` prints the value only; integers '0x%08x %d';
    without --type the type comes from SDO information."""
    assert _ok(ec("upload", "-p", "1", "--type", "string", "0x1008", "0")).text == "io-b\n"
    assert _ok(ec("upload", "-p", "0", "-t", "uint32", "0x1018", "1")).text == f"0x{VENDOR_ID:08x} {VENDOR_ID}\n"
    assert _ok(ec("upload", "-p", "1", "0x1018", "4")).text == "0x00000007 7\n"
    assert _ok(ec("upload", "-p", "0", "0x8000", "1")).text == "generic loop-back I/O test box\n"
    assert _ok(ec("upload", "-p", "0", "--type", "octet_string", "0x1018", "1")).text == "42 4c 57 47\n"


def test_download_then_upload(ec: Ec) -> None:
    """`download --type TYPE INDEX SUB VALUE` writes by SDO; the slave keeps it (over the wire the
    line persists between commands, so the upload reads it back)."""
    _ok(ec("download", "-p", "0", "--type", "uint32", "0x8000", "2", "0x4d2"))
    _ok(ec("download", "-p", "1", "0x8000", "1", "renamed box"))     # type from SDO information
    if ec.kind == "pysoem":
        assert _ok(ec("upload", "-p", "0", "0x8000", "2")).text == "0x000004d2 1234\n"
        assert _ok(ec("upload", "-p", "1", "0x8000", "1")).text == "renamed box\n"


def test_upload_download_unhappy_paths(ec: Ec) -> None:
    """No such object -> abort code and its CiA 301 text (exit 1); a value of the wrong type for the
    object -> the slave's 0x06070013; a value that is not of the type -> usage error (exit 2);
    read-only -> 0x06010002; several slaves without -p or a bad position -> exit 2."""
    _fails(ec("upload", "-p", "0", "0x5FFF", "0"), 1, "SDO abort 0x06020000 for 0x5FFF:00",
           "Object does not exist in the object dictionary")
    _fails(ec("upload", "-p", "0", "0x1018", "9"), 1, "0x06090011", "Sub-index does not exist")
    _fails(ec("download", "-p", "0", "--type", "uint8", "0x8000", "2", "3"), 1, "0x06070013")
    _fails(ec("download", "-p", "0", "--type", "uint32", "0x1018", "1", "1"), 1, "0x06010002",
           "Attempt to write a read only object")
    _fails(ec("download", "-p", "0", "--type", "uint32", "0x8000", "2", "abc"), 2, "not an integer")
    _fails(ec("download", "-p", "0", "--type", "uint8", "0x8000", "2", "300"), 2, "out of range for uint8")
    _fails(ec("upload", "0x1000", "0"), 2, "2 slaves on the line", "-p POSITION")
    _fails(ec("upload", "-p", "9", "0x1000", "0"), 2, "no slave at position 9")
    _fails(ec("upload", "-p", "0", "--type", "uint99", "0x1000", "0"), 2, "invalid choice")
    _fails(ec("upload", "-p", "0", "0x10000", "0"), 2, "outside 0..0xFFFF")


def test_sdos_lists_the_dictionary(ec: Ec) -> None:
    """IgH `ethercat sdos`: 'SDO 0xIIII, "name"' then '  0xIIII:SS, access, type, N bit, "name"'
    per entry (ETG.1000.6 SDO information); -q: objects only."""
    text = _ok(ec("sdos", "-p", "0")).text
    assert 'SDO 0x1018, "Identity"\n  0x1018:00, r-r-r-, uint8, 8 bit, "SubIndex 000"\n' \
           '  0x1018:01, r-r-r-, uint32, 32 bit, "Vendor ID"\n' in text
    assert '  0x8000:02, rwrwrw, uint32, 32 bit, "Scale"\n' in text
    quiet = _ok(ec("sdos", "-p", "0", "-q")).text.splitlines()
    assert quiet[:2] == ['SDO 0x1000, "Device type"', 'SDO 0x1008, "Manufacturer device name"']
    assert all(line.startswith("SDO 0x") for line in quiet) and len(quiet) >= 19
    both = _ok(ec("sdos", "-q")).text
    assert both.startswith("=== Master 0, Slave 0 ===\n") and "=== Master 0, Slave 1 ===\n" in both


def test_pdos_lists_sms_pdos_entries(ec: Ec) -> None:
    """IgH `ethercat pdos`: SyncManagers, assigned PDOs (0x1C12/0x1C13) and mapped entries."""
    assert _ok(ec("pdos", "-p", "0")).text == PDOS_0
    both = _ok(ec("pdos")).text
    assert both == f"=== Master 0, Slave 0 ===\n{PDOS_0}=== Master 0, Slave 1 ===\n{PDOS_0}"


def test_sii_read_binary_and_hex(ec: Ec) -> None:
    """IgH `ethercat sii_read`: the SII bytes on stdout; identity at words 0x08..0x0F (ETG.2010)."""
    raw = _ok(ec("sii-read", "-p", "1")).out
    assert struct.unpack_from("<IIII", raw, 0x10) == (VENDOR_ID, 0x00010001, 2, 7)
    assert len(raw) % 2 == 0 and raw.find(b"io-b") > 0x80
    lines = _ok(ec("sii-read", "-p", "1", "--hex")).text.splitlines()
    assert lines[1] == "0010: " + raw[0x10:0x20].hex(" ")
    assert len(lines) == (len(raw) + 15) // 16


def test_foe_write_read_and_errors(ec: Ec, tmp_path: Path) -> None:
    """FoE write with a progress bar, read back (over the wire the slave keeps the file), a missing
    file -> FoE error 0x8001 NOT_FOUND (exit 1), an unreadable local file -> exit 2."""
    payload = bytes(range(256)) * 4 + b"end"
    src = tmp_path / "config.bin"
    src.write_bytes(payload)
    r = _ok(ec("foe-write", "-p", "0", str(src), "--progress"))
    assert "foe write config.bin" in r.err and "1.0/1.0 kB" in r.err
    _ok(ec("foe-write", "-p", "1", "-", "-n", "from-stdin.bin", "--no-progress", stdin=b"xyz"))
    if ec.kind == "pysoem":
        assert _ok(ec("foe-read", "-p", "0", "config.bin")).out == payload
        dest = tmp_path / "back.bin"
        _ok(ec("foe-read", "-p", "1", "from-stdin.bin", "-o", str(dest)))
        assert dest.read_bytes() == b"xyz"
    _fails(ec("foe-read", "-p", "0", "missing.bin"), 1, "FoE error 0x8001 NOT_FOUND", "missing.bin")
    _fails(ec("foe-write", "-p", "0", str(tmp_path / "nope.bin")), 2, "cannot read")


def test_line_must_be_given(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Neither -i nor --rig (or both): a usage error, exit 2; a missing rig file too."""
    assert cli_main(["ec", "slaves"]) == 2
    assert "-i IFNAME" in capsys.readouterr().err
    assert cli_main(["ec", "slaves", "--rig", str(tmp_path / "none.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_help_has_examples(capsys: pytest.CaptureFixture[str]) -> None:
    """Every verb's --help ends with an example command line."""
    from gatewaylab.cli.ec import VERBS

    for verb in VERBS:
        with pytest.raises(SystemExit) as exc:
            cli_main(["ec", verb, "--help"])
        assert exc.value.code == 0
        assert f"gatewaylab ec {verb} " in capsys.readouterr().out


# ------------------------------------------------------------------ helpers
def test_format_and_parse_values() -> None:
    """Values as IgH prints/takes them: signed integers with their two's-complement hex."""
    assert format_value(TYPES["int16"], struct.pack("<h", -2)) == "0xfffe -2"
    assert format_value(TYPES["float"], struct.pack("<f", 1.5)) == "1.5"
    assert format_value(None, b"\x01\xff") == "01 ff"
    assert parse_value(TYPES["int8"], "-128") == b"\x80"
    assert parse_value(TYPES["octet_string"], "01 02ff") == b"\x01\x02\xff"
    assert parse_value(TYPES["double"], "2") == struct.pack("<d", 2.0)


def test_state_path_follows_the_esm() -> None:
    """ETG.1000.6 state machine: up one state at a time, down directly, BOOT only via INIT."""
    assert state_path(AlState.PREOP, AlState.OP) == [AlState.SAFEOP, AlState.OP]
    assert state_path(AlState.OP, AlState.INIT) == [AlState.INIT]
    assert state_path(AlState.PREOP, AlState.BOOT) == [AlState.INIT, AlState.BOOT]
    assert state_path(AlState.BOOT, AlState.PREOP) == [AlState.INIT, AlState.PREOP]
    assert state_path(AlState.BOOT, AlState.INIT) == [AlState.INIT]

