"""``gatewaylab ec master --serve SOCKET``: a persistent master the other verbs attach to with
``--master SOCKET`` (issue 25: every call re-opened the line and slaves in OP fell to SAFEOP with
0x001B, as IgH's master module, which stays up, never lets them)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

RIG = """clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
[ethercat]
interface = "gl-none"
"""
WAIT = 120.0


def ec(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "ec", *args], capture_output=True, text=True,
                          timeout=WAIT)


@contextmanager
def serving(rig: Path, sock: str) -> Iterator[subprocess.Popen[str]]:
    """``gatewaylab ec master --rig RIG --serve SOCK`` as a child (killed if a test leaves it running)."""
    server = subprocess.Popen([sys.executable, "-m", "gatewaylab", "ec", "master", "--rig", str(rig), "--serve", sock],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert server.stdout is not None
        yield server
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()


def test_slaves_stay_in_op_between_calls_of_a_persistent_master(tmp_path: Path) -> None:
    """ETG.1000.6 SM watchdog: a master that keeps exchanging process data keeps its slaves in OP; the
    verbs of separate calls see the state the previous call left (a one-shot --rig starts in PREOP)."""
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    sock = str(tmp_path / "ec.sock")
    with serving(rig, sock) as server:
        assert server.stdout is not None
        banner = server.stdout.readline()
        assert banner.startswith(f"master serving --rig {rig} on {sock} (2 slaves"), banner
        assert ec("states", "--rig", str(rig)).stdout.split("\n")[0].split()[1] == "PREOP"   # one-shot
        up = ec("states", "--master", sock, "OP")
        assert up.returncode == 0, up.stderr
        assert [ln.split()[:3] for ln in up.stdout.splitlines()] == [["0", "OP", "+"], ["1", "OP", "+"]]
        time.sleep(0.5)
        again = ec("states", "--master", sock)
        assert [ln.split()[:3] for ln in again.stdout.splitlines()] == [["0", "OP", "+"], ["1", "OP", "+"]]
        value = ec("upload", "--master", sock, "-p", "1", "0x1018", "1")
        assert value.returncode == 0 and value.stdout.strip(), value.stderr
        # ESC registers (IgH reg_read / reg_write): a write that persists between calls
        assert ec("reg-read", "--master", sock, "-p", "0", "0x0130", "2").stdout == "0x08 0x00\n"   # AL status OP
        assert ec("reg-write", "--master", sock, "-p", "1", "--type", "uint16", "0x0012", "0x1234").returncode == 0
        assert ec("reg-read", "--master", sock, "-p", "1", "--type", "uint16", "0x0012").stdout == "0x1234 4660\n"
        far = ec("reg-read", "--master", sock, "-p", "0", "0xFFFF", "2")
        assert far.returncode == 2 and "go past the ESC's 64 KiB" in far.stderr
        info = ec("master", "--master", sock)
        assert "Slaves: 2" in info.stdout and "Process data: mapped" in info.stdout, info.stdout
        exchanges = int(info.stdout.split("Process data: mapped, cycle 2 ms, ")[1].split()[0])
        assert exchanges > 0
        bad = ec("upload", "--master", sock, "-p", "5", "0x1018", "1")
        assert bad.returncode == 2 and bad.stderr.startswith("gatewaylab ec upload: no slave at position 5")
        assert ec("sii-read", "--master", sock, "-p", "0").returncode == 2          # no binary through it
        stopped = ec("master", "--master", sock, "--stop")
        assert stopped.returncode == 0
        assert server.wait(WAIT) == 0 and not Path(sock).exists()


def test_no_master_at_the_socket_is_one_line(tmp_path: Path) -> None:
    out = ec("slaves", "--master", str(tmp_path / "none.sock"))
    assert out.returncode == 2 and "no master serving there (start one: gatewaylab ec master --serve" in out.stderr
    assert "Traceback" not in out.stderr


ECRT_STUB = """#include <stddef.h>
#include <stdint.h>
/* the declarations of IgH's ecrt.h that cstruct's output uses (IgH EtherCAT master 1.5 API) */
typedef enum { EC_DIR_INVALID, EC_DIR_OUTPUT, EC_DIR_INPUT, EC_DIR_COUNT } ec_direction_t;
typedef enum { EC_WD_DEFAULT, EC_WD_ENABLE, EC_WD_DISABLE } ec_watchdog_mode_t;
typedef struct { uint16_t index; uint8_t subindex; uint8_t bit_length; } ec_pdo_entry_info_t;
typedef struct { uint16_t index; unsigned int n_entries; ec_pdo_entry_info_t const *entries; } ec_pdo_info_t;
typedef struct { uint8_t index; ec_direction_t dir; unsigned int n_pdos; ec_pdo_info_t const *pdos;
                 ec_watchdog_mode_t watchdog_mode; } ec_sync_info_t;
"""


def test_cstruct_is_c_an_igh_application_compiles(tmp_path: Path) -> None:
    """IgH ``ethercat cstruct``: the slave's SyncManagers, PDOs and entries as ec_sync_info_t /
    ec_pdo_info_t / ec_pdo_entry_info_t; the output compiles against ecrt.h's declarations and
    holds the io slave's layout (SM2 outputs 0x1600 with 3 entries, SM3 inputs 0x1A00 with 4)."""
    import shutil
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    out = ec("cstruct", "--rig", str(rig), "-p", "1")
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert '/* Master 0, Slave 1, "io-b"' in text
    assert "    {0x1600, 3, slave_1_pdo_entries + 0}, /* Outputs */" in text
    assert "    {0x1a00, 4, slave_1_pdo_entries + 3}, /* Inputs */" in text
    assert "    {2, EC_DIR_OUTPUT, 1, slave_1_pdos + 0, EC_WD_ENABLE}," in text
    assert "    {3, EC_DIR_INPUT, 1, slave_1_pdos + 1, EC_WD_DISABLE}," in text
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return                     # the content checks above still hold
    source = tmp_path / "pdos.c"
    source.write_text(ECRT_STUB + text + "int main(void) { return slave_1_syncs[4].index == 0xff ? 0 : 1; }\n")
    built = subprocess.run([compiler, "-Wall", "-Werror", "-o", str(tmp_path / "pdos"), str(source)],
                           capture_output=True, text=True, timeout=WAIT)
    assert built.returncode == 0, built.stderr
    assert subprocess.run([str(tmp_path / "pdos")], timeout=WAIT).returncode == 0


def test_xml_is_an_esi_of_what_the_line_says(tmp_path: Path) -> None:
    """IgH ``ethercat xml``: an EtherCATInfo document (ETG.2000) per slave: vendor, type with product code
    and revision, SyncManagers, RxPdo/TxPdo with their entries; well-formed XML."""
    import xml.etree.ElementTree as ET
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    out = ec("xml", "--rig", str(rig), "-p", "0")
    assert out.returncode == 0, out.stderr
    root = ET.fromstring(out.stdout)
    device = root.find("Descriptions/Devices/Device")
    assert root.tag == "EtherCATInfo" and device is not None
    assert int(root.findtext("Vendor/Id") or "0") == 0x47574C42
    assert device.find("Type").attrib == {"ProductCode": "#x00010001", "RevisionNo": "#x00000001"}  # type: ignore[union-attr]
    assert [sm.attrib["StartAddress"] for sm in device.findall("Sm")] == ["#x1000", "#x1080", "#x1100", "#x1400"]
    rx, tx = device.find("RxPdo"), device.find("TxPdo")
    assert rx is not None and tx is not None and rx.attrib["Sm"] == "2" and tx.attrib["Sm"] == "3"
    assert [(e.findtext("Index"), e.findtext("BitLen"), e.findtext("DataType")) for e in tx.findall("Entry")] == [
        ("#x6000", "8", "UINT8"), ("#x6010", "16", "UINT16"), ("#x6010", "16", "UINT16"), ("#x6020", "32", "UINT32")]
