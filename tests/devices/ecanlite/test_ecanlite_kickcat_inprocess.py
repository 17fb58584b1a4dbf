"""The SyncManagers KickCAT 2.5 programs, checked in process: ``Bus::configureFMMUs`` writes SM2/SM3 with
control bytes 0x64 / 0x20 (3-buffer) whatever the SII says (0x66 / 0x22, manual 5.3). The ECAN-Lite
accepts them when three buffers fit (N <= 8: 0x1100 + 3 * 1024 = 0x1D00, SM3's start), runs the 5.4.4.1
frame through them with the full working counter, and refuses N = 9 and more with AL 0x001D."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from ecanlite_device_kit import Rig, configure_channels, make_rig

from gatewaylab.bus import python_can_bus
from gatewaylab.devices.ecanlite.image import INPUTS_START, OUTPUTS_START
from gatewaylab.devices.ecanlite.stream import crc16
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError
from gatewaylab.ethercat.esc import REG_SM, AlState


def _assign(rig: Rig, n: int) -> None:
    """5.4.3 phases B and C for ``n`` chunks."""
    m = rig.master
    for assign, base in ((0x1C12, 0x1600), (0x1C13, 0x1A00)):
        m.sdo_download8(0, assign, 0, 0)
        for i in range(n):
            m.sdo_download16(0, assign, i + 1, base + i)
        m.sdo_download8(0, assign, 0, n)
    for index in (0x8010, 0x8011):
        m.sdo_download8(0, index, 3, n)
        m.sdo_download8(0, index, 1, 1)
        assert m.sdo_upload8(0, index, 2) == 0


def _kickcat_sms(rig: Rig, n: int) -> None:
    """SM2 / SM3 as KickCAT writes them: SII start, mapped length, 0x64 / 0x20, enabled."""
    station = rig.master.slaves[0].station
    rig.master.fpwr(station, REG_SM + 16, struct.pack("<HHBBBB", OUTPUTS_START, 128 * n, 0x64, 0, 1, 0))
    rig.master.fpwr(station, REG_SM + 24, struct.pack("<HHBBBB", INPUTS_START, 128 * n, 0x20, 0, 1, 0))


@pytest.mark.parametrize("n", [3, 8])
def test_three_buffer_syncmanagers_run_the_manual_frame(tmp_path: Path, n: int) -> None:
    """5.4.3 / 5.4.4.1 with KickCAT's 3-buffer SM2/SM3: SAFEOP and OP are granted, every LRW has the
    expected working counter, `40 00 23 01 11 22 33 44 55 66 77 88` reaches CAN0 once as 0x123, and the
    TxPDO header comes back with the device's layout (chapter 6)."""
    rig = make_rig(tmp_path)
    m = rig.master
    m.set_state(AlState.PREOP)
    _assign(rig, n)
    configure_channels(rig)
    m.config_map()
    _kickcat_sms(rig, n)
    m.set_state(AlState.SAFEOP)
    m.exchange_process_data()
    m.set_state(AlState.OP)
    client = python_can_bus(rig.buses[0])
    try:
        image = bytearray(128 * n)
        image[24:36] = bytes.fromhex("40 00 23 01 11 22 33 44 55 66 77 88")
        word = (n - 1) & 0x1F | (0x0F << 5)
        layout_id = (word ^ (word >> 16)) & 0xFFFF
        struct.pack_into("<BBHHHHHBBBB", image, 0, 0x16, 0, 1, 0, 12, crc16(image[24:36]), layout_id, 0x0F, 1, 0, 1)
        struct.pack_into("<H", image, 4, 1)
        m.pdo_write(0, 0, bytes(image))
        assert all(rig.cycle(1) == m.expected_wkc for _ in range(20))
        msg = client.recv(0)
        assert msg is not None and msg.arbitration_id == 0x123
        assert bytes(msg.data) == bytes.fromhex("11 22 33 44 55 66 77 88")
        assert client.recv(0) is None
        header = m.pdo_read(0, 0, 24)
        assert header[0] == 0x16 and struct.unpack_from("<H", header, 10)[0] == layout_id
        assert m.sdo_upload16(0, 0x8011, 14) == 0 and m.sdo_upload32(0, 0x8011, 15) == 0
    finally:
        client.shutdown()


def test_three_buffers_that_do_not_fit_are_refused(tmp_path: Path) -> None:
    """N = 9: three buffers of 1152 B from 0x1100 run into SM3 at 0x1D00, so SAFEOP is refused with
    0x001D invalid output configuration (ETG.1000.6); the SII's 1-buffer mode still works for N = 9."""
    rig = make_rig(tmp_path)
    m = rig.master
    m.set_state(AlState.PREOP)
    _assign(rig, 9)
    m.config_map()
    _kickcat_sms(rig, 9)
    with pytest.raises(AlStatusError) as err:
        m.request_state(0, AlState.SAFEOP)
    assert err.value.code == AlStatusCode.INVALID_OUTPUT_CONFIG
    m.request_state(0, AlState.PREOP, ack=True)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    m.exchange_process_data()
    m.set_state(AlState.OP)
    assert rig.cycle(3) == m.expected_wkc
