"""``gatewaylab ec domains``, ``data`` and ``config`` (IgH ``ethercat domains/data/config``, issue 25), in
process (``--rig``), through SOEM on a veth pair (``-i``, its own module: its own namespace) and through a
persistent master (``--master SOCKET``). Expected values come from the slaves' own PDO description (io_device:
what their SII and 0x1C12/0x1C13 + 0x16xx/0x1Axx say, ETG.1000.6), not from the verbs' code: the
domain's size is the sum of the mapped bytes, and the expected working counter follows IgH's rule for one
LRW datagram (ETG.1000.4 LRW: +2 for a slave's written outputs, +1 for its read inputs)."""

from __future__ import annotations

import itertools
import re
import time
from pathlib import Path

import pytest
import test_ec_cli
from test_ec_cli import RIG, Ec, InProcessEc, _fails, _ok
from test_ec_cli_esd import ESD_RIG
from test_ec_master_server import WAIT, serving
from test_ec_master_server import ec as ec_process

from gatewaylab.devices.ethercat_io.device import VENDOR_ID, io_description

#: test_ec_cli's fixtures: RIG's line in process and over SOEM (``pysoem``: in this module's own namespace).
line = test_ec_cli.ec
wire_segment = test_ec_cli.wire_segment

DOMAIN = re.compile(r"Domain0: LogBaseAddr 0x([0-9a-f]{8}), Size +(\d+), WorkingCounter (\d+)/(\d+)$")
FMMU = re.compile(r"  SlaveConfig 0:(\d+), SM(\d+) \( ?(Output|Input)\), LogAddr 0x([0-9a-f]{8}), Size (\d+)$")


def _u(ec: Ec, pos: int, index: int, sub: int, ctype: str) -> int:
    """One unsigned value by SDO upload (``0x.. decimal``)."""
    return int(_ok(ec("upload", "-p", str(pos), "--type", ctype, f"0x{index:04X}", str(sub))).text.split()[0], 16)


def mapping(output: bool) -> list[tuple[int, int, int, int]]:
    """[(pdo, index, sub, bits)] of an ethercat_io box's RxPDOs (``output``) or TxPDOs, from its device
    description (io_device.io_description: what its SII and 0x1C12/0x1C13 say)."""
    desc = io_description()
    return [(p.index, e.index, e.subindex, e.bit_length) for p in (desc.rx_pdos if output else desc.tx_pdos)
            for e in p.entries]


def expected_domain(count: int) -> tuple[int, int, dict[tuple[int, bool], int]]:
    """(size, expected working counter, {(slave, output): bytes}) of ``count`` ethercat_io boxes; one LRW
    datagram: each slave with outputs counts 2, with inputs 1 (IgH ec_domain: 2 * outputs + inputs)."""
    sizes = {(pos, out): (sum(e[3] for e in mapping(out)) + 7) // 8 for pos in range(count) for out in (True, False)}
    wkc = sum((2 if output else 1) for (_pos, output), n in sizes.items() if n)
    return sum(sizes.values()), wkc, sizes


def parse_domains(text: str) -> tuple[tuple[int, int, int, int], list[tuple[int, int, bool, int, int]], list[bytes]]:
    lines = text.splitlines()
    m = DOMAIN.match(lines[0])
    assert m, text
    head = (int(m[1], 16), int(m[2]), int(m[3]), int(m[4]))
    fmmus, data = [], []
    for k, ln in enumerate(lines):
        f = FMMU.match(ln)
        if f:
            fmmus.append((int(f[1]), int(f[2]), f[3] == "Output", int(f[4], 16), int(f[5])))
            data.append(bytes.fromhex(lines[k + 1]))
    return head, fmmus, data


def test_domains_one_shot_maps_and_matches_the_mapping(line: Ec) -> None:
    """IgH ``ethercat domains [-v]``: one domain, its logical base address, size (the mapped PDO bytes of
    every slave) and working counter current/expected after the one exchange a one-shot command makes;
    -v: one FMMU per slave and direction, on SM2 (outputs) / SM3 (inputs) as the SII says, laid out
    without gaps or overlaps over the domain."""
    size, wkc, sizes = expected_domain(2)
    plain = _ok(line("domains")).text
    head, fmmus, _ = parse_domains(plain)
    assert head == (0, size, wkc, wkc)
    assert "  Exchanges 1, WorkingCounter mismatches 0" in plain.splitlines()
    head, fmmus, data = parse_domains(_ok(line("domains", "-v")).text)
    assert sorted((pos, out, n) for pos, _sm, out, _a, n in fmmus) == sorted(
        (pos, out, n) for (pos, out), n in sizes.items() if n)
    sm_of = {True: 2, False: 3}
    assert all(sm == sm_of[out] for _p, sm, out, _a, _n in fmmus)
    covered = sorted((a, a + n) for _p, _sm, _o, a, n in fmmus)
    assert covered[0][0] == head[0] and covered[-1][1] == head[0] + head[1]
    assert all(end == nxt for (_s, end), (nxt, _e) in itertools.pairwise(covered))
    assert [len(d) for d in data] == [f[4] for f in fmmus]
    binary = _ok(line("data")).out
    assert len(binary) == size
    assert _ok(line("data", "--hex")).text.splitlines()[0].startswith("0000: ")
    _fails(line("domains", "-d", "1"), 2, "no domain 1")


def test_config_lists_the_slave_configurations(line: Ec) -> None:
    """IgH ``ethercat config``: ``alias:position  vendor/product  slave  state`` per configuration; -v the
    SyncManagers with direction and watchdog and the PDOs with their entries, as the box's PDO
    description says (ETG.1000.6 0x1C12/0x1C13, 0x16xx/0x1Axx)."""
    rows = [ln.split() for ln in _ok(line("config")).text.splitlines()]
    product = f"0x{VENDOR_ID:08x}/0x{_u(line, 0, 0x1018, 2, 'uint32'):08x}"
    assert rows == [["0:0", product, "0", "PREOP"], ["0:1", product, "1", "PREOP"]]
    text = _ok(line("config", "-v", "-p", "1")).text
    assert text.startswith(f"Alias: 0\nPosition: 1\nVendor Id: 0x{VENDOR_ID:08x}\n")
    assert "Attached slave: 1 (PREOP)\n" in text
    outs, ins = mapping(True), mapping(False)
    want = ["SM2, Dir: Output, Watchdog: Enable"]
    for entries in (outs, ins):
        for pdo in dict.fromkeys(e[0] for e in entries):
            want.append(f"  PDO 0x{pdo:04x}")
            want += [f"    PDO entry 0x{i:04x}:{s:02x}, {b:2d} bit" for p, i, s, b in entries if p == pdo]
        if entries is outs:
            want.append("SM3, Dir: Input, Watchdog: Disable")
    body = text.split("Watchdog intervals: (Default)\n")[1].split("SDO configuration:")[0]
    assert body.splitlines() == want
    assert text.endswith("SDO configuration:\n  None.\nIDN configuration:\n  None.\nFeature flags:\n  None.\n\n")
    _fails(line("config", "-p", "4"), 2, "no slave at position 4")


def test_domains_and_data_of_a_persistent_master(tmp_path: Path) -> None:
    """Through ``--master SOCKET`` the verbs report the persistent master's live domain: mapped by the
    first verb that needs it, then cycling (exchanges grow between calls, the working counter is the
    expected one in OP, the slaves' cycle counters 0x6020:01 move); ``data`` writes no binary through
    it (as sii-read/foe-read), ``data --hex`` does."""
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    sock = str(tmp_path / "ec.sock")
    with serving(rig, sock) as server:
        assert server.stdout is not None
        assert server.stdout.readline().startswith("master serving")
        size, wkc, sizes = expected_domain(2)
        first = ec_process("domains", "--master", sock, "-v")      # maps the segment
        assert first.returncode == 0, first.stderr
        assert parse_domains(first.stdout)[0][:2] == (0, size)
        up = ec_process("states", "--master", sock, "OP")
        assert up.returncode == 0, up.stderr
        time.sleep(0.3)
        a = ec_process("domains", "--master", sock, "-v")
        time.sleep(0.3)
        b = ec_process("domains", "--master", sock, "-v")
        (base, got_size, cur, exp), fmmus, data_a = parse_domains(a.stdout)
        assert (base, got_size, exp) == (0, size, wkc) and cur == wkc, a.stdout
        runs = [int(re.search(r"Exchanges (\d+)", t.stdout)[1]) for t in (a, b)]   # type: ignore[index]
        assert runs[1] > runs[0] > 0
        _head, _f, data_b = parse_domains(b.stdout)
        counters = [[int.from_bytes(d[5:9], "little") for d, f in zip(ds, fmmus, strict=True) if not f[2]]
                    for ds in (data_a, data_b)]
        assert all(y > x for x, y in zip(counters[0], counters[1], strict=True)), counters
        assert sizes[(0, False)] == 9     # inputs: 8 + 16 + 16 + 32 bit, the cycle counter at byte 5
        refused = ec_process("data", "--master", sock)
        assert refused.returncode == 2 and "data through --master writes no binary to stdout: give --hex" in \
            refused.stderr
        listing = ec_process("data", "--master", sock, "--hex")
        assert listing.returncode == 0 and sum(len(ln.split()) - 1 for ln in listing.stdout.splitlines()) == size
        info = ec_process("master", "--master", sock).stdout
        assert f"last working counter {wkc}" in info, info
        config = ec_process("config", "--master", sock)
        assert [ln.split()[3] for ln in config.stdout.splitlines()] == ["OP", "OP"]
        assert ec_process("master", "--master", sock, "--stop").returncode == 0
        assert server.wait(WAIT) == 0


def sdo_mapped_bytes(ec: Ec, pos: int, assign: int) -> int:
    """Bytes one slave maps in a direction, by SDO: the assignment ``assign`` (0x1C12 outputs, 0x1C13
    inputs) and each assigned PDO's entries (index << 16 | subindex << 8 | bit length, ETG.1000.6)."""
    bits = 0
    for i in range(1, _u(ec, pos, assign, 0, "uint8") + 1):
        pdo = _u(ec, pos, assign, i, "uint16")
        bits += sum(_u(ec, pos, pdo, j, "uint32") & 0xFF for j in range(1, _u(ec, pos, pdo, 0, "uint8") + 1))
    return (bits + 7) // 8


def test_domains_of_a_mixed_line_match_the_sdo_mapping(tmp_path: Path,
                                                       capsysbinary: pytest.CaptureFixture[bytes]) -> None:
    """An ethercat_io box and the esd gateway (MDP 5000 queues, a 380-byte image): the domain's FMMUs
    and size agree with what each slave's 0x1C12/0x1C13 mapping says by SDO, and the expected working
    counter with IgH's rule (2 per slave with outputs, 1 per slave with inputs)."""
    rig = tmp_path / "esd.toml"
    rig.write_text(ESD_RIG)
    ec = InProcessEc(rig, capsysbinary)
    sizes = {(pos, out): sdo_mapped_bytes(ec, pos, 0x1C12 if out else 0x1C13)
             for pos in (0, 1) for out in (True, False)}
    wkc = sum((2 if out else 1) for (_p, out), n in sizes.items() if n)
    (base, size, cur, exp), fmmus, _data = parse_domains(_ok(ec("domains", "-v")).text)
    assert (base, size, cur, exp) == (0, sum(sizes.values()), wkc, wkc)
    assert {(pos, out): n for pos, _sm, out, _a, n in fmmus} == {k: n for k, n in sizes.items() if n}
    assert len(_ok(ec("data")).out) == size
