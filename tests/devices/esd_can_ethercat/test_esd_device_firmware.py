"""BOOT state, FoE firmware update and reboot (manual 5.3, 2.2.1 'Bootstrap'), the web pages' backend
(chapter 6) and the rig kind, on a simulated clock."""

from __future__ import annotations

import json
import urllib.request
from typing import Any

import pytest

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esd_can_ethercat.webmodel import EsdWebModel
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError, FoeError, FoeErrorCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.rig import Rig
from gatewaylab.rig.config import parse_rig

IMAGE = b"CAN-EtherCAT firmware 2.4\n" + bytes(range(256)) * 40   # 10 kB, several FoE packets


def _boot(kit: Any) -> None:
    kit.master.request_state(0, AlState.INIT)
    kit.master.request_state(0, AlState.BOOT)


def test_foe_firmware_update_in_boot_then_reboot_with_the_new_version(kit: Any) -> None:
    """5.3.1: Bootstrap, FoE 'firmwareUpdate' with password 0, wait for the update (here 3 s on the
    clock instead of about 3 minutes), the device restarts (INIT) and 0x100A shows the new version."""
    m = kit.master
    _boot(kit)
    assert m.al_status(0)[0] == AlState.BOOT
    m.foe_write(0, "firmwareUpdate", IMAGE, password=0)
    assert kit.gw.updating
    kit.clock.advance(1.0)
    assert m.al_status(0)[0] == AlState.BOOT
    kit.clock.advance(2.5)
    assert m.al_status(0) == (AlState.INIT, 0) and not kit.gw.updating
    m.request_state(0, AlState.PREOP)
    assert m.sdo_upload_str(0, 0x100A) == "2.4"
    assert m.sdo_upload32(0, 0x1018, 1) == 0x17


@pytest.mark.parametrize(("name", "password", "data", "code"), [
    ("firmwareUpdate", 1, IMAGE, FoeErrorCode.NO_RIGHTS),
    ("firmware.bin", 0, IMAGE, FoeErrorCode.NOT_FOUND),
    ("firmwareUpdate", 0, b"", FoeErrorCode.ILLEGAL),
])
def test_foe_refusals_in_boot(kit: Any, name: str, password: int, data: bytes, code: int) -> None:
    """5.3.2 'Set the file name string to firmwareUpdate and leave the password at 00000000':
    anything else is refused with an FoE error; nothing starts."""
    _boot(kit)
    with pytest.raises(FoeError) as err:
        kit.master.foe_write(0, name, data, password=password)
    assert err.value.code == code and not kit.gw.updating


def test_foe_outside_boot_is_an_foe_error(kit: Any) -> None:
    """5.3.1 step 2 'Set the slave in the state Bootstrap' first: in PREOP the download is refused with
    FoE error 0x8008 'bootstrap only'."""
    kit.preop()
    with pytest.raises(FoeError) as err:
        kit.master.foe_write(0, "firmwareUpdate", IMAGE)
    assert err.value.code == FoeErrorCode.BOOTSTRAP_ONLY and not kit.gw.updating


def test_boot_is_reached_from_init_only_and_left_to_init(kit: Any) -> None:
    """ETG state machine (soem-interop note): INIT -> BOOT -> INIT; PREOP -> BOOT is refused."""
    kit.preop()
    with pytest.raises(AlStatusError) as err:
        kit.master.request_state(0, AlState.BOOT)
    assert err.value.code == AlStatusCode.INVALID_STATE_CHANGE
    _boot(kit)
    kit.master.request_state(0, AlState.INIT)
    kit.master.request_state(0, AlState.PREOP)


def test_an_image_without_a_version_line_keeps_the_version(kit: Any) -> None:
    """The accepted file format (docs/devices/esd_can_ethercat.md): a first line 'CAN-EtherCAT
    firmware X.Y' sets 0x100A; other images update and reboot but keep the version."""
    _boot(kit)
    kit.master.foe_write(0, "firmwareUpdate", b"\x7fELF" + bytes(300))
    kit.clock.advance(3.5)
    kit.master.request_state(0, AlState.PREOP)
    assert kit.master.sdo_upload_str(0, 0x100A) == "2.3"


def test_reboot_restores_the_defaults(kit: Any) -> None:
    """A restart (6.1.3) forgets what the master wrote: queues, bit rate, filters, statistics."""
    m = kit.master
    kit.preop()
    m.sdo_download8(0, 0x8000, 0x21, 4)
    m.sdo_download8(0, 0xF800, 2, 2)
    m.sdo_download64(0, 0x8001, 1, 0x100 | 0x1FF << 32)
    m.sdo_download8(0, 0x8001, 0, 1)
    EsdWebModel(kit.gw).reboot()
    assert m.al_status(0) == (AlState.INIT, 0)
    m.request_state(0, AlState.PREOP)
    assert [m.sdo_upload8(0, 0x8000, 0x21), m.sdo_upload8(0, 0x1A00, 0), m.sdo_upload8(0, 0xF800, 2),
            m.sdo_upload8(0, 0x8001, 0)] == [16, 20, 0xFF, 0]
    assert kit.gw.controller.listen_only and not kit.gw.controller.connected


def test_web_backend_update_progress_like_figure_39(kit: Any) -> None:
    """6.1.2: an upload starts the update, the page shows the output of Figure 39 as it proceeds,
    then the device reboots; a second upload meanwhile, or an empty file, is refused."""
    web = EsdWebModel(kit.gw)
    kit.op()
    assert web.update_progress() is None
    web.start_firmware_update("fw.bin", IMAGE)
    first = web.update_progress()
    assert first is not None and first.startswith("End of file found. All good.\nUnpacking updater.")
    with pytest.raises(ValueError):
        web.start_firmware_update("fw.bin", IMAGE)
    kit.clock.advance(2.9)
    text = web.update_progress()
    assert text is not None and text.rstrip().endswith("Flashing updater and rebooting...")
    kit.clock.advance(0.2)
    assert web.update_progress() is None and kit.master.al_status(0)[0] == AlState.INIT
    assert web.info().firmware == "2.4"
    with pytest.raises(ValueError):
        web.start_firmware_update("empty.bin", b"")


def test_web_backend_views(kit: Any) -> None:
    """6.1.1 / 6.2.1: identity as the device reports it, Figure 41's fields from the statistics."""
    web = EsdWebModel(kit.gw)
    kit.op()
    kit.send([CanFrame(0x1, b"abc"), CanFrame(0x2, rtr=True, dlc=1)])
    kit.peer.send(CanFrame(0x3, b"defg"))
    kit.receive_all()
    info = web.info()
    assert (info.vendor_id, info.product_code, info.revision, info.serial) == ("0x00000017", "0x00000002",
                                                                               "0x00000001", "4660")
    assert info.ethercat_state == "OP" and info.station_address == kit.master.slaves[0].station
    s = web.can_status()
    assert (s.bitrate_set, s.bitrate_actual, s.time_quanta, s.sample_point) == ("0x00000002", 500_000, 20, 85.0)
    assert (s.tx_std_data, s.tx_std_rtr, s.rx_std_data, s.rx_bytes, s.tx_bytes) == (1, 1, 1, 4, 3)
    assert (s.status, s.rx_error_counter, s.tx_error_counter) == ("00", 0, 0)
    assert s.rx_bits > 4 * 8 + 44          # a 4-byte frame: 44 bits of frame overhead, data, stuffing


def _rig(web_port: int) -> Any:
    return parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none", "bitrate": 500000}],
                      "device": [{"kind": "esd_can_ethercat", "name": "esd1", "bus": "can0", "web_port": web_port,
                                  "serial": 0x99}],
                      "ethercat": {"interface": "gl-none"}})


def test_rig_kind_ready_info_and_web_server(tmp_path: Any) -> None:
    """Issue 11 'Rig': listed in ethercat.slaves, the web base URL under "web"; the server answers;
    the rig's ``serial`` is 0x1018:04 (5.1.3.5)."""
    with Rig(_rig(0)) as rig:
        rig.start()
        (esd,) = [p for p in rig.participants if getattr(p, "name", "") == "esd1"]
        assert int(esd.gateway.slave.od.get(0x1018, 4)) == 0x99
        info = json.loads(json.dumps(rig.ready_info()))
        slaves = info["ethercat"]["slaves"]
        assert slaves == [{"name": "esd1", "position": 0, "vendor_id": 0x17, "product_code": 2}]
        url = info["web"]["esd1"]
        assert url.startswith("http://127.0.0.1:") and url.endswith("/")
        with urllib.request.urlopen(url + "status/can", timeout=10) as resp:
            page = resp.read().decode()
        assert resp.status == 200 and "Value set by canSetBaudrate() : 0x7fffffff" in page


def test_rig_web_port_in_use_fails_cleanly() -> None:
    """A web port that is taken stops the start with one error; nothing keeps running."""
    with Rig(_rig(0)) as rig:
        rig.start()
        port = int(rig.ready_info()["web"]["esd1"].rsplit(":", 1)[1].strip("/"))
        second = Rig(_rig(port))
        with pytest.raises(ConfigError):
            second.start()
        participant = second.participants[0]
        assert participant.web is None and participant.gateway.controller is None
        second.close()


def test_foe_write_request_outside_boot_is_refused_before_any_data(kit: Any) -> None:
    """5.3.1 step 2 (Bootstrap first): the write request itself gets the FoE error 0x8008, so a master
    sends no data packet in vain (ETG.1000.6 FoE: an ERR packet may answer a WRQ)."""
    from gatewaylab.ethercat.foe import FOE_HEADER, FoeOpcode, foe_packet
    from gatewaylab.ethercat.mailbox import MailboxType

    kit.preop()
    reply = kit.master.mailbox_exchange(0, MailboxType.FOE, foe_packet(FoeOpcode.WRQ, 0, b"firmwareUpdate"))
    opcode, _res, code = FOE_HEADER.unpack_from(reply.data, 0)
    assert (opcode, code) == (FoeOpcode.ERR, FoeErrorCode.BOOTSTRAP_ONLY)
