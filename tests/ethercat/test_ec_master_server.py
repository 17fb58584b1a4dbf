"""``gatewaylab ec master --serve SOCKET``: a persistent master the other verbs attach to with
``--master SOCKET`` (issue 25: every call re-opened the line and slaves in OP fell to SAFEOP with
0x001B, as IgH's master module, which stays up, never lets them)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
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


def test_slaves_stay_in_op_between_calls_of_a_persistent_master(tmp_path: Path) -> None:
    """ETG.1000.6 SM watchdog: a master that keeps exchanging process data keeps its slaves in OP; the
    verbs of separate calls see the state the previous call left (a one-shot --rig starts in PREOP)."""
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    sock = str(tmp_path / "ec.sock")
    server = subprocess.Popen([sys.executable, "-m", "gatewaylab", "ec", "master", "--rig", str(rig), "--serve", sock],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
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
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()


def test_no_master_at_the_socket_is_one_line(tmp_path: Path) -> None:
    out = ec("slaves", "--master", str(tmp_path / "none.sock"))
    assert out.returncode == 1 and "no master serving there (start one: gatewaylab ec master --serve" in out.stderr
    assert "Traceback" not in out.stderr
