"""Golden frames: SOEM's config_init conversation, recorded once on the veth pair (data/soem_config_init.pcap:
every request followed by the emulator's answer), replayed against fresh slaves without any network.

Every answer must come back byte for byte: station addresses, SII EEPROM interface, AL status,
DL status, SyncManager registers and working counters as SOEM saw them when it accepted the slaves.
Regenerate (root) by serving make_segment()'s slaves with a PcapWriter while SOEM runs config_init.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.datagram import decode_frame
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire_pcap import read_pcap

GOLDEN = Path(__file__).parent / "data" / "soem_config_init.pcap"


def test_soem_config_init_replays_byte_for_byte() -> None:
    """shared notes 'soem-interop': the registers SOEM touches (BRD 0x0000 count, APWR 0x0010, FPRD
    0x0110/0x0130, SII 0x0502..0x050F) answered exactly as on the wire."""
    frames = [f for _t, f in read_pcap(GOLDEN.read_bytes())]
    assert len(frames) > 200 and len(frames) % 2 == 0
    clock = SimulatedClock()
    segment = Segment([create_io_slave(clock, f"GL-IO #{i}", serial=1000 + i, revision=i + 1) for i in range(3)])
    commands: set[str] = set()
    for i in range(0, len(frames), 2):
        request, expected = bytearray(frames[i]), frames[i + 1]
        assert segment.process(request)
        assert bytes(request) == expected, f"frame pair {i // 2}: {decode_frame(expected).datagrams}"
        commands.update(d.command.name for d in decode_frame(expected).datagrams)
    assert {"BRD", "BWR", "APRD", "APWR", "FPRD", "FPWR"} <= commands
    assert [s.esc.station_address for s in segment.slaves] == [0x1001, 0x1002, 0x1003]


def test_golden_capture_is_wellformed_for_wireshark() -> None:
    """The recorded capture opens in Wireshark's EtherCAT dissector with no malformed frame."""
    tshark = shutil.which("tshark")
    if tshark is None:
        pytest.skip("tshark (Wireshark) is not installed")
    out = subprocess.run([tshark, "-r", str(GOLDEN), "-T", "fields", "-e", "frame.protocols", "-e", "_ws.malformed"],
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert len(out) > 200
    assert all(line.split("\t")[0].endswith("ecat") and not line.split("\t")[1] for line in out)
