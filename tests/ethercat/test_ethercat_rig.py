"""The EtherCAT rig participants, the `gatewaylab net` command and a whole real-time rig driven by SOEM."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.cli.main import main as cli_main
from gatewaylab.devices.ethercat_io.device import PRODUCT_CODE, VENDOR_ID
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "{clock}"
[[device]]
kind = "ethercat_io"
name = "io-a"
revision = 1
[[device]]
kind = "ethercat_io"
name = "io-b"
revision = 2
serial = 7
[ethercat]
interface = "{iface}"
"""


def _rig(tmp_path: Path, clock: str, iface: str) -> Rig:
    path = tmp_path / "rig.toml"
    path.write_text(RIG.format(clock=clock, iface=iface))
    return Rig.from_file(path)


def test_rig_segment_in_file_order_and_ready_info(tmp_path: Path) -> None:
    """Rig file: the EtherCAT devices form the segment in file order; --ready-file reports them."""
    with _rig(tmp_path, "simulated", "gl-none") as rig:
        rig.start()
        info = rig.ready_info()["ethercat"]
        assert info["interface"] == "gl-none"
        assert info["slaves"] == [
            {"name": "io-a", "position": 0, "vendor_id": VENDOR_ID, "product_code": PRODUCT_CODE},
            {"name": "io-b", "position": 1, "vendor_id": VENDOR_ID, "product_code": PRODUCT_CODE}]
        segment = next(p for p in rig.participants if getattr(p, "name", "") == "ethercat").segment  # type: ignore[attr-defined]
        m = Master(rig.clock, segment)
        assert [(s.name, s.serial) for s in m.scan()] == [("io-a", 0), ("io-b", 7)]


def test_rig_without_interface_is_refused(tmp_path: Path) -> None:
    """An [ethercat] section must name its interface (issue 5: `[ethercat] interface = "NAME"`)."""
    path = tmp_path / "rig.toml"
    path.write_text('clock = "simulated"\n[[device]]\nkind = "ethercat_io"\n[ethercat]\npcap = "x"\n')
    with pytest.raises(Exception, match="interface"):
        Rig.from_file(path)


def test_net_up_and_down(veth_ns: Any, capsys: pytest.CaptureFixture[str]) -> None:
    """`gatewaylab net up NAME` creates NAME and NAME-m and prints both; `down` removes them."""
    name = f"gln{os.getpid() % 10000}"
    assert cli_main(["net", "up", name]) == 0
    try:
        out = capsys.readouterr().out
        assert name in out and f"{name}-m" in out
        assert subprocess.run(["ip", "link", "show", f"{name}-m"], capture_output=True).returncode == 0
    finally:
        assert cli_main(["net", "down", name]) == 0
    assert subprocess.run(["ip", "link", "show", name], capture_output=True).returncode != 0


@pytest.mark.net
def test_realtime_rig_answers_soem(veth_ns: Any, tmp_path: Path) -> None:
    """A real-time rig serving `[ethercat] interface` is found by SOEM's config_init with its names."""
    rig = _rig(tmp_path, "realtime", veth_ns.emulator_iface)
    thread = rig.run_in_thread()
    try:
        proc = veth_ns.run_master("config")
    finally:
        rig.request_stop()
        thread.join(5)
        rig.close()
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert [s["name"] for s in result["slaves"]] == ["io-a", "io-b"]
    assert [s["rev"] for s in result["slaves"]] == [1, 2]


@pytest.mark.net
def test_gatewaylab_run_ready_file_and_soem(veth_ns: Any, tmp_path: Path) -> None:
    """`gatewaylab run RIG --ready-file F` with an [ethercat] section: the ready file carries the
    interface and the slaves; SOEM on the peer finds them; SIGTERM stops the rig."""
    import signal
    import sys

    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG.format(clock="realtime", iface=veth_ns.emulator_iface))
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen([sys.executable, "-m", "gatewaylab.cli.main", "run", str(rig_file), "--ready-file",
                             str(ready)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # printed once the ready file is in place
        assert "running" in line, (line, proc.stderr.read() if proc.stderr else "")
        info = json.loads(ready.read_text())["ethercat"]
        assert info["interface"] == veth_ns.emulator_iface
        assert [(s["name"], s["position"]) for s in info["slaves"]] == [("io-a", 0), ("io-b", 1)]
        result = veth_ns.run_master("config")
        assert result.returncode == 0, result.stderr[-2000:]
        assert [s["name"] for s in json.loads(result.stdout.splitlines()[-1])["slaves"]] == ["io-a", "io-b"]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
    assert proc.returncode == 0
