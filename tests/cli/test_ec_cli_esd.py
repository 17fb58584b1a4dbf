"""``gatewaylab ec`` against the gateways (esd CAN-EtherCAT, ECAN-Lite), in process (``--rig``) and through SOEM
on a veth pair (its own module: its own namespace, so no other wire answers on the interface)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_ec_cli import Ec, InProcessEc, PysoemEc, _fails, _ok

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

# ------------------------------------------------------------------ the esd CAN-EtherCAT gateway
ESD_RIG = """clock = "simulated"
[[bus]]
name = "can0"
bitrate = 500000
endpoint = "none"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"
serial = 0x1234
update_seconds = 0.2
[ethercat]
interface = "gl-none"
"""


@pytest.fixture(scope="module")
def esd_wire_segment(veth_ns: Any) -> Iterator[Segment]:
    """An ethercat_io slave and the esd gateway (ESD_RIG's line) on the emulator end of the veth."""
    from gatewaylab.bus import VirtualBus
    from gatewaylab.devices.esd_can_ethercat.device import EsdGateway

    clock = RealTimeClock()
    gateway = EsdGateway(clock, VirtualBus(clock, "can0", 500_000), "esd1", 0x1234, 0.2)
    gateway.start()
    segment = Segment([create_io_slave(clock, "io-a"), gateway.slave])
    wire = WireTransport(segment, veth_ns.emulator_iface, clock, drive_clock=True)
    wire.start()
    try:
        yield segment
    finally:
        wire.stop()
        gateway.stop()


@pytest.fixture(params=["inprocess", pytest.param("pysoem", marks=[pytest.mark.net, pytest.mark.slow])])
def esd_ec(request: pytest.FixtureRequest, tmp_path: Path, capsysbinary: pytest.CaptureFixture[bytes]) -> Ec:
    if request.param == "inprocess":
        rig = tmp_path / "esd.toml"
        rig.write_text(ESD_RIG)
        return InProcessEc(rig, capsysbinary)
    return PysoemEc(request.getfixturevalue("veth_ns"), request.getfixturevalue("esd_wire_segment"))


def test_esd_gateway_verbs(esd_ec: Ec, tmp_path: Path) -> None:
    """The esd gateway (docs/devices/esd_can_ethercat.md) through the same verbs: its name and
    identity, its MDP 5000 PDOs (0x1600 'CAN RxPDO-Map' on SM2, 0x1A00 on SM3), its dictionary;
    FoE 'firmwareUpdate' outside BOOT is FoE error 0x8008 (esd manual 5.3), with --boot it is taken."""
    assert _ok(esd_ec("slaves")).text == "0  0:0  PREOP  +  io-a\n1  0:1  PREOP  +  CAN-EtherCAT\n"
    assert _ok(esd_ec("upload", "-p", "1", "0x1018", "4")).text == "0x00001234 4660\n"
    pdos = _ok(esd_ec("pdos", "-p", "1")).text.splitlines()
    assert pdos[2].startswith("SM2: PhysAddr 0x1100") and pdos[3] == '  RxPDO 0x1600 "CAN RxPDO-Map"'
    assert pdos[4] == '    PDO entry 0x7000:01, 16 bit, "Tx Counter"'
    assert any(line == '  TxPDO 0x1a00 "CAN TxPDO-Map"' for line in pdos)
    assert 'SDO 0x1018, "Identity"' in _ok(esd_ec("sdos", "-p", "1", "-q")).text
    firmware = tmp_path / "fw.bin"
    firmware.write_bytes(b"esd firmware image" * 20)
    _fails(esd_ec("foe-write", "-p", "1", str(firmware), "-n", "firmwareUpdate"), 1, "FoE error 0x8008")
    _fails(esd_ec("foe-write", "-p", "0", str(firmware), "--boot"), 1, "0x0013 BOOTSTRAP_NOT_SUPPORTED")
    _ok(esd_ec("foe-write", "-p", "1", str(firmware), "-n", "firmwareUpdate", "--boot"))   # then it reboots


# ------------------------------------------------------------------ both gateways on one line
GATEWAYS_RIG = """clock = "simulated"
[[bus]]
name = "can0"
bitrate = 1000000
data_bitrate = 5000000
endpoint = "none"
[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can0"]
[[device]]
kind = "esd_can_ethercat"
name = "esd1"
bus = "can0"
"""


def test_both_gateways_in_process(tmp_path: Path, capsysbinary: pytest.CaptureFixture[bytes]) -> None:
    """ECAN-Lite (docs/devices/ecanlite.md: SM2 at 0x1100, 1-buffer 0x66, 128-byte chunk PDOs
    0x1600..) and the esd gateway on one line: names, 0x1008, PDOs, the way to OP."""
    rig = tmp_path / "gateways.toml"
    rig.write_text(GATEWAYS_RIG)
    ec = InProcessEc(rig, capsysbinary)
    assert _ok(ec("slaves")).text == "0  0:0  PREOP  +  ECAN-Lite\n1  0:1  PREOP  +  CAN-EtherCAT\n"
    assert _ok(ec("upload", "-p", "0", "--type", "string", "0x1008", "0")).text == "ECAN-Lite\n"
    pdos = _ok(ec("pdos", "-p", "0")).text.splitlines()
    assert pdos[2].startswith("SM2: PhysAddr 0x1100,") and pdos[2].endswith("ControlRegister 0x66, Enable 1")
    assert pdos[3] == '  RxPDO 0x1600 "Chunk 0"' and pdos[4] == '    PDO entry 0x7000:01, 128 bit, "Unit 0"'
    assert _ok(ec("states", "OP")).text == "0  OP      +  0x0000 NO_ERROR\n1  OP      +  0x0000 NO_ERROR\n"
