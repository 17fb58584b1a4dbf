"""``gatewaylab migrate config -i IFNAME -p POS``: a running esd gateway's dictionary read through
SOEM (pysoem) over a veth pair the test creates in its own namespace (the pattern of
tests/ethercat/conftest.py ``veth_ns``), translated as its ENI would be (issue 13 part 1)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from wire_kit import net_capable, veth_namespace

from gatewaylab.bus import VirtualBus
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport
from gatewaylab.migrate.eni import parse_eni

pytestmark = [pytest.mark.net, pytest.mark.slow]


def _net_reason() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip (tests/wire_kit.py)."""
    return net_capable("pysoem")


@dataclass(frozen=True)
class Veth:
    namespace: str
    emulator: str
    master: str


@pytest.fixture(scope="module")
def veth() -> Iterator[Veth]:
    reason = _net_reason()
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-mig-", "glm") as (ns, emu, mst):
        yield Veth(ns, emu, mst)


def test_migrate_config_from_running_esd(veth: Veth, tmp_path: Path) -> None:
    """The esd's 0xF800:02 = 3 (Table 6: 250 kbit/s) and one 0x8001 area, read over the wire, give
    the ECAN-Lite ENI: 250 kbit/s on MCAN0, one standard filter, N = 3 for the default 16 + 16 queues."""
    clock = RealTimeClock()
    gateway = EsdGateway(clock, VirtualBus(clock, "can0", 250_000), "esd1", 0x1234, 0.2)
    od = gateway.slave.od
    od.put(0xF800, 2, 3)
    od.put(0x8001, 1, 0x0000017F_00000100)
    od.put(0x8001, 0, 1)
    gateway.start()
    wire = WireTransport(Segment([gateway.slave]), veth.emulator, clock, drive_clock=True)
    wire.start()
    try:
        out, report = tmp_path / "ecan.xml", tmp_path / "r.md"
        proc = subprocess.run(["ip", "netns", "exec", veth.namespace, sys.executable, "-m", "gatewaylab.cli.main",
                               "migrate", "config", "-i", veth.master, "-p", "0", "-o", str(out),
                               "--report", str(report)], capture_output=True, text=True, timeout=120, check=False)
    finally:
        wire.stop()
        gateway.stop()
    assert proc.returncode == 0, proc.stderr
    assert "N = 3" in proc.stdout
    slave = parse_eni(out.read_text())[0]
    writes = {(c.index, c.subindex): c.value for c in slave.init_cmds}
    assert writes[(0x8001, 19)] == 250_000
    assert (writes[(0x8001, 53)], writes[(0x8001, 54)], writes[(0x8001, 49)]) == (0x100, 0x17F, 1)
    assert "0xF800:02 u8 0x3" in report.read_text()
