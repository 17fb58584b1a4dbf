"""FoE OTA through the whole device (15.3.1): a good package makes the device leave the line, come
back in INIT and show the new version in 0x100A and 0xF000:05/06; bad ones change nothing."""

from __future__ import annotations

from pathlib import Path

import pytest
from ecanlite_device_kit import bring_up, make_rig

from gatewaylab.devices.ecanlite.device import RESET_TIME
from gatewaylab.devices.ecanlite.ota import FirmwareVersion, pack
from gatewaylab.ethercat.errors import FoeError
from gatewaylab.ethercat.esc import AlState


def test_good_package_resets_the_device_with_the_new_version(tmp_path: Path) -> None:
    """15.3.1: `foe_write ecan_lite_app` password 0 with a packaged image; the slave resets (gone from
    the line for a moment, then INIT), a rescan shows 0x100A and 0xF000:05/06 of the package."""
    rig = make_rig(tmp_path)
    bring_up(rig, n=3)
    m = rig.master
    old = m.sdo_upload_str(0, 0x100A)
    package = pack(b"\x13" * 3000, FirmwareVersion(1, 4, 0x0494))
    m.foe_write(0, "ecan_lite_app", package, password=0)
    rig.clock.advance(0.01)
    assert rig.device.slave.esc.offline
    assert m.scan() == []  # nobody answers while it restarts
    rig.clock.advance(RESET_TIME)
    assert not rig.device.slave.esc.offline and rig.device.slave.state == AlState.INIT
    assert len(m.scan()) == 1
    m.set_state(AlState.PREOP)
    new = m.sdo_upload_str(0, 0x100A)
    assert new != old and "1.4" in new and "0494" in new
    assert m.sdo_upload16(0, 0xF000, 5) == 0x0104 and m.sdo_upload16(0, 0xF000, 6) == 0x0494
    assert rig.device.resets == 1
    bring_up(rig, n=3)  # the restarted device runs again
    assert rig.cycle(2) == m.expected_wkc


@pytest.mark.parametrize("name, password, data", [
    ("ecan_lite_app", 1, None),
    ("other_file", 0, None),
    ("ecan_lite_app", 0, b"\x13" * 3000),   # a bare app image
    ("ecan_lite_app", 0, b"corrupt"),
])
def test_refused_packages_leave_the_version(tmp_path: Path, name: str, password: int, data: bytes | None) -> None:
    """15.3.1 common mistakes: wrong password, wrong name, bare or corrupted image -> an FoE error,
    the device stays in the line and the version does not change."""
    rig = make_rig(tmp_path)
    m = rig.master
    m.set_state(AlState.PREOP)
    old = m.sdo_upload_str(0, 0x100A)
    payload = data if data is not None else pack(b"\x13" * 3000, FirmwareVersion(1, 4, 0x0494))
    with pytest.raises(FoeError):
        m.foe_write(0, name, payload, password=password)
    rig.clock.advance(RESET_TIME * 2)
    assert not rig.device.slave.esc.offline and rig.device.resets == 0
    assert m.sdo_upload_str(0, 0x100A) == old


def test_flash_round_trip_through_a_reset(tmp_path: Path) -> None:
    """13.4 / 13.7: a channel configuration saved to flash (0xB000:04 bit0) is what the device runs
    after a restart (0x8000:01 reboot); the flash file is the rig's."""
    rig = make_rig(tmp_path)
    m = rig.master
    m.set_state(AlState.PREOP)
    m.sdo_download32(0, 0x8002, 19, 250_000)
    m.sdo_download8(0, 0xB000, 4, 0x01)
    rig.clock.advance(0.01)
    assert (tmp_path / "ecan.flash").exists()
    m.sdo_download32(0, 0x8002, 19, 125_000)  # not saved
    m.sdo_download8(0, 0x8000, 1, 1)           # restart
    rig.clock.advance(0.01)
    rig.clock.advance(RESET_TIME)
    assert rig.device.resets == 1
    m.scan()
    m.set_state(AlState.PREOP)
    assert m.sdo_upload32(0, 0x8002, 19) == 250_000
