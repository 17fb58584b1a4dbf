"""Issue 13 part 1 round trip: esd ENI -> ECAN-Lite ENI -> applied by a master to an in-process
ECAN-Lite, which reaches OP with 128 x N bytes and the translated channel settings (ECAN-Lite
manual 5.4.1-5.4.3, 13.2, 13.4; QEC master manual A.7: InitCmds in PREOP -> SAFEOP)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.cli.main import main
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.devices.esd_can_ethercat import create_esd_gateway
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.migrate.config import ecanlite_slave, find_esd, read_live
from gatewaylab.migrate.eni import InitCmd, SlaveConfig, parse_eni, write_eni
from gatewaylab.migrate.translate import translate


def u(index: int, sub: int, value: int, size: int) -> InitCmd:
    return InitCmd(index, sub, value.to_bytes(size, "little"))


ESD_CMDS = (u(0xF800, 2, 3, 1), u(0x8000, 0x20, 1, 2), u(0x8000, 0x22, 40, 1), u(0x8000, 0x21, 24, 1),
            u(0x8001, 0, 2, 1), u(0x8001, 1, 0x0000017F_00000100, 8),
            u(0x8001, 2, 0x80002000_80001000, 8),
            u(0x1C13, 0, 0, 1), u(0x1C13, 1, 0x1A00, 2), u(0x1C13, 2, 0x1A85, 2), u(0x1C13, 0, 2, 1))
ESD_SLAVE = SlaveConfig("esd CAN-EtherCAT", 0x17, 2, 1, init_cmds=ESD_CMDS, output_bits=8 * (6 + 40 * 16),
                        input_bits=8 * (8 + 24 * 14 + 6), dc_cycle0=1_000_000, dc_shift=0)


def apply_eni(master: Master, slave: SlaveConfig) -> None:
    """What an ENI master does (A.7): PREOP, the CoE InitCmds, map, SAFEOP, OP."""
    master.scan()
    s = master.slave(0)
    assert (s.vendor_id, s.product_code) == (slave.vendor_id, slave.product_code)
    master.set_state(AlState.PREOP)
    for c in slave.init_cmds:
        master.sdo_download(0, c.index, c.subindex, c.data, complete=c.complete_access)
    assert 8 * master.config_map() == slave.output_bits + slave.input_bits
    master.set_state(AlState.SAFEOP)
    master.exchange_process_data()
    master.set_state(AlState.OP)


@pytest.mark.parametrize(("channel", "complete"), [(0, False), (2, True)])
def test_ecanlite_reaches_op_with_translated_eni(channel: int, complete: bool) -> None:
    """5.4.2: 0x8010/0x8011 status 0 and active bytes 128 x N; 13.4: apply status 0, the bit rate,
    classic CAN, the filters; 16.1: OP only with SM lengths equal to 128 x N."""
    esd = find_esd(parse_eni(write_eni([ESD_SLAVE])))
    tr = translate(esd.init_cmds, channel, complete)
    eni = write_eni([ecanlite_slave(esd, tr)])
    slave = parse_eni(eni)[0]                                  # the produced ENI parses again
    assert slave.init_cmds == tuple(InitCmd(c.index, c.subindex, c.data, c.complete_access, "PS", c.comment)
                                    for c in tr.cmds)
    assert (slave.dc_cycle0, slave.dc_shift) == (1_000_000, 0)
    n = tr.multiplier
    assert n == 5                                               # 40 x 14 + 24 = 584 B -> 5 chunks
    clock = SimulatedClock()
    buses = [VirtualBus(clock, f"can{k}", 250_000) for k in range(4)]
    ecan = EcanLiteDevice(clock, [b.attach(f"ecan.mcan{k}") for k, b in enumerate(buses)])
    master = Master(clock, Segment([ecan.slave]))
    apply_eni(master, slave)
    assert master.al_status(0)[0] == AlState.OP
    cfg = 0x8001 + channel
    for index in (0x8010, 0x8011):
        assert master.sdo_upload8(0, index, 2) == 0
        assert master.sdo_upload16(0, index, 9) == 128 * n
        assert master.sdo_upload8(0, index, 4) == 1 << channel
    assert master.sdo_upload8(0, cfg, 2) == 0
    assert master.sdo_upload32(0, cfg, 19) == 250_000          # Table 6 index 3
    assert master.sdo_upload8(0, cfg, 15) == 0
    assert (master.sdo_upload8(0, cfg, 49), master.sdo_upload8(0, cfg, 55)) == (1, 1)
    assert master.sdo_upload8(0, 0x8010, 7) == 1               # TX_RESULT
    # the filter: 0x120 (inside 0x100..0x17F) reaches the channel, 0x200 does not
    peer = buses[channel].attach("peer")
    peer.send(CanFrame(0x200, b"\x01"))
    peer.send(CanFrame(0x120, b"\x02"))
    clock.advance(0.01)
    ch = ecan.model.channels[channel]
    assert [r.frame.can_id for r in ch.peek(8)] == [0x120]


def test_read_live_esd_equals_eni() -> None:
    """-i/-p's reader: the esd's dictionary after the ENI's InitCmds gives the same translation."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", 250_000)
    esd = create_esd_gateway(clock, bus, "esd1")
    master = Master(clock, Segment([esd.slave]))
    master.scan()
    master.set_state(AlState.PREOP)
    for c in ESD_CMDS:
        master.sdo_download(0, c.index, c.subindex, c.data, complete=c.complete_access)
    expected = [(c.index, c.subindex, c.value) for c in translate(ESD_CMDS).cmds]
    assert [(c.index, c.subindex, c.value) for c in translate(read_live(master, 0)).cmds] == expected
    backend = InProcessBackend(master)                         # the host libraries' master API (issue 12)
    assert [(c.index, c.subindex, c.value) for c in translate(read_live(backend, 0)).cmds] == expected


def test_cli_config_and_esi(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`gatewaylab migrate config esd.xml -o ecanlite.xml --report r.md`, `migrate esi`: the ESI is
    the device's export (identity = the SII's) and the ENI's identity matches it."""
    (tmp_path / "esd.xml").write_text(write_eni([ESD_SLAVE]))
    assert main(["migrate", "config", str(tmp_path / "esd.xml"), "-o", str(tmp_path / "e.xml"),
                 "--report", str(tmp_path / "r.md")]) == 0
    out = capsys.readouterr().out
    assert "N = 5" in out and "0x1A85 status PDO" in out
    report = (tmp_path / "r.md").read_text()
    assert "40 x 14 = 560 B" in report
    eni = parse_eni((tmp_path / "e.xml").read_text())[0]
    assert main(["migrate", "esi", "--device", "ecanlite", "-o", str(tmp_path / "ecan.xml")]) == 0
    esi = (tmp_path / "ecan.xml").read_text()
    assert f'ProductCode="#x{eni.product_code:08X}" RevisionNo="#x{eni.revision:08X}"' in esi
    assert main(["migrate", "esi", "--device", "esd_can_ethercat", "-o", str(tmp_path / "esd_esi.xml")]) == 0
    assert main(["migrate", "config", str(tmp_path / "missing.xml"), "-o", str(tmp_path / "x.xml")]) == 2  # not found
    assert main(["migrate", "config", "-o", str(tmp_path / "x.xml")]) == 2       # neither INPUT nor -i
    assert main(["migrate"]) == 2
    (tmp_path / "bad.txt").write_text("0xF800:02 u8 300\n")
    assert main(["migrate", "config", str(tmp_path / "bad.txt"), "-o", str(tmp_path / "x.xml")]) == 2
