"""SOEM (pysoem) against the esd CAN-EtherCAT over a veth pair in a test-made network namespace (manual
4.2, 5.1.3, 5.1.5, 5.3): identity, SDO Information, default sizes, both handshakes with several
batches, 29-bit mode, a Table 6 bit rate, BOOT + FoE. The emulator side runs the segment and a CAN
echo node on one real-time clock."""

from __future__ import annotations

import json
from typing import Any

import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.esd_can_ethercat.device import create_esd_gateway
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport

pytestmark = [pytest.mark.net, pytest.mark.slow]
CHATTER_ID = 0x7F0


def _serve(veth: Any, *args: str, update_duration: float = 1.0, chatter: bool = False) -> tuple[dict[str, Any], Any]:
    """The gateway on a 500 kbit/s bus with an echo node (id + 0x100), served on the veth while the
    driver runs; with ``chatter`` two more nodes exchange a frame (0x7F0) every 10 ms (autobaud
    needs them). Returns the driver's JSON and the gateway."""
    clock = RealTimeClock()
    bus = VirtualBus(clock, "can0", bitrate=500_000)
    gw = create_esd_gateway(clock, bus, "esd1", serial=0x4711, update_duration=update_duration)
    echo = bus.attach("echo")

    def answer(frame: CanFrame, t: float) -> None:
        if frame.can_id != CHATTER_ID:
            echo.send(CanFrame(frame.can_id + 0x100, frame.data, extended=frame.extended))

    echo.on_frame = answer
    if chatter:
        talker = bus.attach("talker")
        bus.attach("listener")
        clock.call_every(0.01, lambda: talker.send(CanFrame(CHATTER_ID, b"chat")))
    wire = WireTransport(Segment([gw.slave]), veth.emulator_iface, clock, drive_clock=True)
    wire.start()
    try:
        proc = veth.run_master(*args)
    finally:
        wire.stop()
        gw.stop()
    assert proc.returncode == 0, " | ".join(proc.stderr.strip().splitlines()[-6:])
    assert not wire.errors
    return json.loads(proc.stdout.strip().splitlines()[-1]), gw


@pytest.fixture(scope="module")
def identity_run(esd_veth: Any) -> dict[str, Any]:
    return _serve(esd_veth, "identity")[0]


def test_soem_reads_identity_and_standard_objects(identity_run: dict[str, Any]) -> None:
    """5.1.3.1-5.1.3.6 through SOEM: SII identity (vendor 0x17, product 2), 0x1000 13881389h,
    0x1008 "MEESC", versions, 0x1018 (revision = SII, serial), 0x1C00 types 1-4."""
    r = identity_run
    assert r["count"] == 1 and (r["man"], r["id"], r["rev"]) == (0x17, 2, 1)
    assert r["name"] == "CAN-EtherCAT"
    assert (r["device_type"], r["device_name"], r["hw"], r["sw"]) == (0x13881389, "MEESC", "1.2", "2.3")
    assert r["identity"] == [0x17, 2, 1, 0x4711]
    assert r["sm_types"] == [4, 1, 2, 3, 4]


def test_soem_sdo_information_object_list(identity_run: dict[str, Any]) -> None:
    """4.2 'Recreate dictionary ... Online from slave': SOEM's SDO Information read lists the objects
    of 5.1.2 with their names (Figure 13)."""
    od = set(identity_run["od"])
    assert {0x1000, 0x1008, 0x1009, 0x100A, 0x1018, 0x1600, 0x1A00, 0x1A85, 0x1C00, 0x1C12, 0x1C13, 0x2000,
            0x2010, 0x6000, 0x6001, 0x7000, 0x7001, 0x8000, 0x8001, 0xF000, 0xF108, 0xF800} <= od
    assert identity_run["od_names"]["0x1600"] == "CAN RxPDO-Map"
    assert identity_run["od_names"]["0x8000"] == "CAN Interface configuration"


def test_soem_maps_the_default_198_and_168_bytes(identity_run: dict[str, Any]) -> None:
    """4.3 Figure 15: config_map reads 0x1C12/0x1C13 and the mappings by SDO: 198 B out, 168 B in."""
    assert identity_run["map_1600"] == [19, 0x70000110, 0x70000460]
    assert identity_run["op"] == "OP" and identity_run["sizes"] == [198, 168]


@pytest.mark.parametrize(("mode", "sizes"), [(11, [198, 168]), (29, [262, 232])])
def test_soem_runs_both_handshakes_with_several_batches(esd_veth: Any, mode: int, sizes: list[int]) -> None:
    """5.1.5.1-5.1.5.4 through SOEM at 500 kbit/s (0xF800:02 = 2): Tx batches of 5, 16 and 8 frames
    acknowledged by the Tx counter and sent in order, the echoes read back as Rx batches (at most 16)
    acknowledged by the Rx counter; the Tx transaction number ends at the last frame's; 29-bit
    mode (0x8000:20 bit 0) gives 262/232 bytes."""
    r, _gw = _serve(esd_veth, "handshake", str(mode))
    assert r["op"] == "OP" and r["sizes"] == sizes
    assert len(r["acks"]) == 3
    sent = [(cid, data) for cid, data in r["sent"]]
    assert [tuple(x) for x in r["received"]] == [(cid + 0x100, data) for cid, data in sent]
    assert sum(r["rx_batches"]) == 29 and max(r["rx_batches"]) <= 16 and len(r["rx_batches"]) >= 2
    assert r["last_tn"] == 29
    assert r["stats"]["0x30"] == 29 and r["stats"]["0x31"] == 29 and r["stats"]["0x32"] == 29
    assert r["stats"]["0x3e" if mode == 29 else "0x3c"] == 29


def test_soem_foe_firmware_update_in_boot(esd_veth: Any) -> None:
    """5.3: FoE refused outside BOOT (an FoE error: pysoem returns <= 0), accepted in Bootstrap;
    after the update (1 s here) the gateway restarts in INIT and 0x100A shows the new version."""
    r, gw = _serve(esd_veth, "foe", "1.0", update_duration=1.0)
    assert r["preop_result"] <= 0
    assert r["boot_state"] == 3 and r["boot_result"] > 0
    assert r["after_update"] & 0x0F == 1
    assert r["count_again"] == 1 and r["sw"] == "2.7"
    assert gw.updates == 1 and gw.reboots == 1


def test_soem_queue_sizes_filter_status_pdo_bit_rate_modes_and_watchdog(esd_veth: Any) -> None:
    """Through SOEM: 0x8000:21/22 = 4/8 resize the mapping (5.1.5.5) and the image (102 B out,
    48 + 6 B in with 0x1A85 assigned, 5.1.3.9); a filter area 0x100-0x1FF (5.1.5.6); a numerical rate
    (UBRN); 0x2010 counts (5.1.4.2); listen-only and no baud rate send nothing and count the frame
    aborted; autobaud finds 500 kbit/s from two other nodes and goes active; a wrong rate receives
    nothing, counts error frames, shows REC in the 0x1A85 bytes and loses its frame at bus off
    (5.1.5.8, 5.1.5.9); missing process data trips the SM watchdog (SAFEOP + 0x001B, 0x2010:08 = 1)."""
    r, _gw = _serve(esd_veth, "extras", chatter=True)
    assert r["map_sub0"] == [11, 8] and r["op"] == "OP" and r["sizes"] == [102, 54]
    assert r["ack1"] and r["ack2"]
    assert [tuple(x) for x in r["received"]] == [(0x100 + i, f"{i:02x}") for i in range(10)]
    assert max(r["batches"]) <= 4 and sum(r["batches"]) == 10
    assert r["status_ok"] == "000000000000"
    assert (r["counts"]["0x30"], r["counts"]["0x31"], r["counts"]["0x32"], r["counts"]["0x37"]) == (11, 11, 10, 0)
    assert r["counts"]["0x38"] >= 11
    modes = r["modes"]
    assert modes["listen_only"] == {"rx": 0, "aborted": 1}
    assert modes["no_baudrate"] == {"rx": 0, "aborted": 1}
    assert [tuple(x) for x in modes["autobaud"]["rx"]] == [(0x102, "6162")]
    wrong = modes["wrong_rate"]
    assert wrong["rx"] == 0 and wrong["aborted"] == 1 and wrong["error_frames"] > 0 and wrong["rec_max"] > 0
    assert r["after_watchdog"] == [0x14, 0x001B] and r["watchdog_count"] == 1
