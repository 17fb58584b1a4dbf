"""SOEM (pysoem) against three emulated slaves over a veth pair in a test-made network namespace."""

from __future__ import annotations

import json
from typing import Any

import pytest
from wire_kit import lost_allowed

from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.ethercat_io.device import PRODUCT_CODE, VENDOR_ID, create_io_slave
from gatewaylab.ethercat.errors import SdoAbortCode
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport
from gatewaylab.ethercat.wire_pcap import PcapWriter, read_pcap

pytestmark = [pytest.mark.net, pytest.mark.slow]
CYCLES = 10_000


def _serve(veth: Any, args: list[str], pcap: PcapWriter | None = None, segment: Segment | None = None,
           clock: RealTimeClock | None = None) -> tuple[dict[str, Any], Segment]:
    clock = clock or RealTimeClock()
    if segment is None:
        segment = Segment([create_io_slave(clock, f"GL-IO #{i}", serial=1000 + i, revision=i + 1)
                           for i in range(3)])
    wire = WireTransport(segment, veth.emulator_iface, clock, drive_clock=True, pcap=pcap, realtime=True)
    wire.start()
    try:
        proc = veth.run_master(*args)
    finally:
        wire.stop()
    assert proc.returncode == 0, (wire.stats(), proc.stderr[-2000:])
    assert not wire.errors
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    result["wire"] = wire.stats()
    return result, segment


@pytest.fixture(scope="module")
def config_run(veth_ns: Any, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], bytes]:
    path = tmp_path_factory.mktemp("pcap") / "config.pcap"
    pcap = PcapWriter(str(path))
    result, _segment = _serve(veth_ns, ["config"], pcap)
    pcap.close()
    return result, path.read_bytes()


@pytest.fixture(scope="module")
def full_run(veth_ns: Any) -> tuple[dict[str, Any], Segment]:
    return _serve(veth_ns, ["full", str(CYCLES)])


def test_soem_config_init_finds_three_slaves_with_names_and_ids(config_run: tuple[dict[str, Any], bytes]) -> None:
    """SII words 0x08..0x0F carry vendor id, product code, revision; the Strings/General categories
    the name (shared notes 'soem-interop': SII content SOEM needs). config_init ends in INIT (IDX 4.2:
    'Power ON ... switches to state Init')."""
    result, _ = config_run
    assert result["count"] == 3
    assert [s["name"] for s in result["slaves"]] == ["GL-IO #0", "GL-IO #1", "GL-IO #2"]
    assert {s["man"] for s in result["slaves"]} == {VENDOR_ID}
    assert {s["id"] for s in result["slaves"]} == {PRODUCT_CODE}
    assert [s["rev"] for s in result["slaves"]] == [1, 2, 3]
    assert {s["state"] for s in result["slaves"]} == {1}


def test_pcap_capture_holds_both_directions_as_ethernet(config_run: tuple[dict[str, Any], bytes]) -> None:
    """Captures use Ethernet link type 1 so Wireshark's EtherCAT dissector decodes EtherType 0x88A4. Every
    request is followed by its answer (the same datagram index; the source MAC has the locally-administered
    bit set), or by nothing when the wire dropped it as too old (docs/rig.md ``max_residence_ms``): as many
    unanswered requests as the wire counted."""
    result, data = config_run
    frames = [f for _t, f in read_pcap(data)]
    assert len(frames) >= 20
    assert all(f[12:14] == b"\x88\xa4" for f in frames)
    unanswered = 0
    i = 0
    while i < len(frames):
        assert not frames[i][6] & 0x02, f"frame {i}: an answer without its request"
        if i + 1 < len(frames) and frames[i + 1][6] & 0x02:
            assert frames[i + 1][17] == frames[i][17]       # the same datagram index
            i += 2
        else:
            unanswered += 1
            i += 1
    assert unanswered == result["wire"]["frames_dropped_late"]


def test_soem_sdo_strings_records_and_complete_access(full_run: tuple[dict[str, Any], Segment]) -> None:
    """CoE SDO upload expedited (0x1018:01), normal (0x1008 string, 30-byte 0x8000:01 string) and
    complete access of a record (sub 0 padded to 16 bits); download then upload of 0x8000:02."""
    r, _ = full_run
    assert r["name_1008"] == "GL-IO #0"
    assert r["identity_vendor"] == VENDOR_ID
    ca = bytes.fromhex(r["identity_ca"])
    assert ca[0] == 4 and ca[1] == 0 and int.from_bytes(ca[2:6], "little") == VENDOR_ID
    assert int.from_bytes(ca[6:10], "little") == PRODUCT_CODE
    assert r["long_string"] == "generic loop-back I/O test box"
    assert r["scale"] == 1234


def test_soem_sees_sdo_abort_codes(full_run: tuple[dict[str, Any], Segment]) -> None:
    """QEC manual A.5: 0x06020000 object does not exist, 0x06090011 sub-index does not exist,
    0x06010002 write to a read-only object; sent as CoE service 2, command 0x80 (shared notes pitfall 1)."""
    r, _ = full_run
    assert r["aborts"] == {"missing": SdoAbortCode.OBJECT_DOES_NOT_EXIST,
                           "missing_sub": SdoAbortCode.SUBINDEX_DOES_NOT_EXIST,
                           "read_only": SdoAbortCode.READ_ONLY}


def test_soem_foe_write_then_read(full_run: tuple[dict[str, Any], Segment]) -> None:
    """FoE write request, data packets acknowledged one by one, a short last packet; then a read."""
    r, segment = full_run
    assert r["foe_roundtrip"] is True
    store = segment.slaves[0].foe_handler
    assert store.files["config.bin"] == bytes(range(256)) * 3 + b"tail"


def test_soem_config_map_safeop_op(full_run: tuple[dict[str, Any], Segment]) -> None:
    """IDX table 4-17: PS starts cyclic communication, SO lets the slave evaluate setpoints; SOEM's
    expected working counter is 2 per output slave + 1 per input slave."""
    r, _ = full_run
    assert r["safeop"] == 4
    assert r["op"] == 8
    assert r["expected_wkc"] == 9


def test_soem_10000_process_data_cycles_both_ways(full_run: tuple[dict[str, Any], Segment]) -> None:
    """Every LRW returns the expected working counter; inputs echo the outputs of the same LRW and
    the slave's cycle counter advanced once per cycle (ethercat_io loop-back behaviour)."""
    r, segment = full_run
    print(f"SOEM, {CYCLES} cycles: {r['lost']} lost frames (no reply within 2 ms), {r['bad_wkc']} wrong")
    assert r["bad_wkc"] == 0 and r["lost"] <= lost_allowed(CYCLES)
    last = r["last_i"]
    for k, hex_inputs in enumerate(r["inputs"]):
        raw = bytes.fromhex(hex_inputs)
        assert raw[0] == (last + k) & 0xFF  # the slave acts on SM2 before the LRW reads SM3
        assert int.from_bytes(raw[1:3], "little") == last & 0x7FFF
        assert int.from_bytes(raw[3:5], "little", signed=True) == -k
        assert int.from_bytes(raw[5:9], "little") >= CYCLES - r["lost"]
    assert all(s.cycles >= CYCLES - r["lost"] for s in segment.slaves)


def test_soem_stops_sm_watchdog_takes_slaves_to_safeop(full_run: tuple[dict[str, Any], Segment]) -> None:
    """IDX table 4-16 SAFEOP 'using safe default values'; when the master stops, the SM watchdog
    (set to 1 s by SOEM through 0x0420, read back through the same register) expires and the slave
    reports SAFEOP + error with AL status code 0x001B."""
    r, segment = full_run
    assert r["watchdog_ms"] == pytest.approx(1000.0)
    assert r["after_stop"] == [[0x14, 0x001B]] * 3
    assert all(s.outputs == bytes(5) for s in segment.slaves)


def test_soem_segmented_sdo_eeprom_and_sdo_information(full_run: tuple[dict[str, Any], Segment]) -> None:
    """A 285-byte string written and read back by segmented SDO; the SII read through SOEM's EEPROM
    access (word 8 = vendor id); SOEM's object dictionary listing through SDO Information."""
    r, _ = full_run
    assert r["segmented_roundtrip"] is True
    assert r["eeprom_vendor"] == VENDOR_ID
    assert r["od_names"] == {"0x1000": "Device type", "0x1018": "Identity", "0x1c12": "RxPDO assign",
                             "0x7010": "Analog outputs"}
    assert r["od_count"] >= 19
    assert r["od_1018_entries"] == ["SubIndex 000", "Vendor ID", "Product code", "Revision", "Serial number"]


def test_soem_receives_coe_emergency(full_run: tuple[dict[str, Any], Segment]) -> None:
    """CoE emergency (service 1) delivered through the mailbox reaches SOEM's emergency callback."""
    r, _ = full_run
    assert r["emergencies"] == [0x5432]


def test_soem_dc_configuration_starts_sync0(full_run: tuple[dict[str, Any], Segment]) -> None:
    """SOEM config_dc (receive-time latch 0x0900, offsets 0x0920, delays 0x0928) and dc_sync
    (0x0990 start, 0x09A0 cycle, 0x0981 activation) -> the devices get SYNC0 events."""
    r, segment = full_run
    assert r["dc_slaves"]
    assert all(getattr(s.app, "sync0_count", 0) > 10 for s in segment.slaves)


def test_soem_with_a_slave_without_mailbox(veth_ns: Any) -> None:
    """A slave without CoE/FoE (no mailbox SMs; process data in SM0/SM1, sizes from the SII TxPDO/RxPDO
    categories) next to a CoE slave: SOEM maps both and reaches OP with the expected working counter."""
    from gatewaylab.ethercat.description import DeviceDescription, Pdo, PdoEntry
    from gatewaylab.ethercat.slave import Slave, SlaveApplication

    class Invert(SlaveApplication):
        def on_outputs(self, slave: Slave, data: bytes) -> None:
            slave.write_inputs(bytes([data[0] ^ 0xFF]))

    clock = RealTimeClock()
    desc = DeviceDescription(name="GL-DIO 8", vendor_id=VENDOR_ID, product_code=0x00020001, coe=False, foe=False,
                             rx_pdos=(Pdo(0x1600, "Out", (PdoEntry(0x7000, 1, 8, "DO"),)),),
                             tx_pdos=(Pdo(0x1A00, "In", (PdoEntry(0x6000, 1, 8, "DI"),)),),
                             outputs_start=0x1000, inputs_start=0x1080)
    segment = Segment([create_io_slave(clock, "GL-IO"), Slave(clock, desc, Invert())])
    r, _ = _serve(veth_ns, ["mixed"], segment=segment, clock=clock)
    assert r["count"] == 2 and r["names"] == ["GL-IO", "GL-DIO 8"]
    assert r["image"] == 5 + 1 + 9 + 1
    assert r["op"] == 8 and r["expected_wkc"] == 6
    assert r["wkcs"] == [6, 6, 6], r["lost"]
    assert r["dio_input"] == "f0"



def test_soem_with_one_buffer_chunked_layout(veth_ns: Any, chunked_description: Any) -> None:
    """ECAN-Lite manual 5.3 layout (SM2 0x1100 / SM3 0x1D00, control 0x66 / 0x22, first N = 3
    chunks of 0x1600../0x1A00.. assigned, 48 PDOs in the dictionary): SOEM maps 384 B each way
    and every cycle of the 1-buffer handshake gets the expected working counter."""
    import dataclasses

    from gatewaylab.ethercat.slave import Slave, SlaveApplication

    class Invert(SlaveApplication):
        def on_outputs(self, slave: Slave, data: bytes) -> None:
            slave.write_inputs(bytes(b ^ 0xFF for b in data))

    clock = RealTimeClock()
    desc = dataclasses.replace(chunked_description, outputs_control=0x66, inputs_control=0x22,
                               rx_assign=(0x1600, 0x1601, 0x1602), tx_assign=(0x1A00, 0x1A01, 0x1A02))
    r, segment = _serve(veth_ns, ["cycles", "500"], segment=Segment([Slave(clock, desc, Invert())]), clock=clock)
    assert r["count"] == 1 and r["names"] == ["chunked"]
    assert r["image"] == 768 and r["sizes"] == [384, 384]
    assert r["op"] == 8 and r["expected_wkc"] == 3 and r["bad_wkc"] == 0 and r["lost"] <= lost_allowed(500)
    assert bytes.fromhex(r["input"]) == bytes([r["last_i"] & 0xFF ^ 0xFF]) * 384
    assert segment.slaves[0].esc.stats.refused_accesses == 0
