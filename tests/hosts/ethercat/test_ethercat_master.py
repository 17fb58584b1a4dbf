"""The in-process master against the same ``ethercat_io`` devices: no network, simulated clock."""

from __future__ import annotations

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import PRODUCT_CODE, VENDOR_ID
from gatewaylab.ethercat.coe import CoeAccessBits, CoeService
from gatewaylab.ethercat.description import DeviceDescription
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError, FoeError, FoeErrorCode, SdoAbort, SdoAbortCode
from gatewaylab.ethercat.esc import REG_SM, AlState
from gatewaylab.ethercat.foe import FoeFiles
from gatewaylab.ethercat.mailbox import MailboxType, decode_mailbox
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import Access, DataType


def test_scan_reads_identity_and_names_from_sii(master: Master) -> None:
    """QEC 3.1 'Slave Information': vendor id and product code of every slave, from the SII."""
    assert [s.name for s in master.slaves] == ["GL-IO #0", "GL-IO #1", "GL-IO #2"]
    assert all(s.vendor_id == VENDOR_ID and s.product_code == PRODUCT_CODE for s in master.slaves)
    assert [s.serial for s in master.slaves] == [1000, 1001, 1002]
    assert [s.station for s in master.slaves] == [0x1001, 0x1002, 0x1003]


def test_typed_sdo_helpers_like_the_qec_library(master: Master) -> None:
    """QEC 'CoE functions' sdoUpload8/16/32 and sdoDownload8/16/32: typed expedited transfers."""
    master.request_state(0, AlState.PREOP)
    assert master.sdo_upload32(0, 0x1018, 1) == VENDOR_ID
    assert master.sdo_upload8(0, 0x1C12, 0) == 1
    assert master.sdo_upload16(0, 0x1C12, 1) == 0x1600
    master.sdo_download32(0, 0x8000, 2, 0xCAFE)
    assert master.sdo_upload32(0, 0x8000, 2) == 0xCAFE
    assert master.sdo_upload_str(0, 0x1008) == "GL-IO #0"


def test_segmented_download_and_upload(master: Master) -> None:
    """A 300-byte string exceeds the 128-byte mailbox: normal initiate + segments both ways."""
    master.request_state(1, AlState.PREOP)
    text = bytes(range(32, 127)) * 3 + b"end!!"
    master.sdo_download(1, 0x8000, 1, text)
    assert master.sdo_upload(1, 0x8000, 1) == text


def test_complete_access_record_upload_and_download(master: Master) -> None:
    """Complete access: all sub-indices in one transfer, sub 0 padded to 16 bits (ETG.1000.6)."""
    master.request_state(0, AlState.PREOP)
    raw = master.sdo_upload(0, 0x1C12, 0, complete=True)
    assert raw[:2] == b"\x01\x00" and raw[2:4] == b"\x00\x16"
    master.sdo_download(0, 0x1C12, 0, b"\x01\x00\x00\x16", complete=True)
    assert master.sdo_upload16(0, 0x1C12, 1) == 0x1600


@pytest.mark.parametrize(("call", "code"), [
    (lambda m: m.sdo_upload(0, 0x5FFF, 0), SdoAbortCode.OBJECT_DOES_NOT_EXIST),
    (lambda m: m.sdo_upload(0, 0x1018, 7), SdoAbortCode.SUBINDEX_DOES_NOT_EXIST),
    (lambda m: m.sdo_download32(0, 0x1018, 1, 5), SdoAbortCode.READ_ONLY),
    (lambda m: m.sdo_download8(0, 0x8000, 2, 5), SdoAbortCode.LENGTH_TOO_LOW),
    (lambda m: m.sdo_download(0, 0x1018, 1, b"\0" * 6), SdoAbortCode.READ_ONLY),
    (lambda m: m.sdo_download16(0, 0x1600, 1, 0), SdoAbortCode.LENGTH_TOO_LOW),
    (lambda m: m.sdo_download32(0, 0x1600, 1, 0x70000108), SdoAbortCode.SUBINDEX_CANNOT_BE_WRITTEN),
])
def test_sdo_abort_codes(master: Master, call: object, code: int) -> None:
    """QEC appendix A.5: the slave answers misuse with the ETG.1000.6 abort code."""
    master.request_state(0, AlState.PREOP)
    with pytest.raises(SdoAbort) as err:
        call(master)  # type: ignore[operator]
    assert err.value.code == code


def test_pdo_assignment_is_preop_only(master: Master) -> None:
    """PDO assignment (0x1C12) may change in PREOP only: 0x08000022 'because of the present device state'."""
    master.set_state(AlState.PREOP)
    master.config_map()
    master.request_state(0, AlState.SAFEOP)
    with pytest.raises(SdoAbort) as err:
        master.sdo_download8(0, 0x1C12, 0, 0)
    assert err.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE


def test_sdo_information_lists_and_describes(master: Master) -> None:
    """QEC 3.4 getObjectDescription(0x1C12): data type, max sub-index, object code, name."""
    master.request_state(0, AlState.PREOP)
    indexes = master.od_list(0)
    for index in (0x1000, 0x1008, 0x1009, 0x100A, 0x1018, 0x1C00, 0x1C12, 0x1C13, 0x1600, 0x1A00,
                  0x1C32, 0x1C33):
        assert index in indexes
    desc = master.object_description(0, 0x1C12)
    assert (desc.data_type, desc.object_code, desc.name) == (DataType.UNSIGNED16, 8, "RxPDO assign")
    entry = master.entry_description(0, 0x7010, 1)
    assert entry.data_type == DataType.INTEGER16 and entry.bit_length == 16
    assert entry.access & CoeAccessBits.RXPDO and entry.name == "Analog output 1"
    assert master.od_list(0, 3) == [0x6000, 0x6010, 0x6020]
    with pytest.raises(SdoAbort) as err:
        master.object_description(0, 0x4321)
    assert err.value.code == SdoAbortCode.OBJECT_DOES_NOT_EXIST


def test_foe_write_read_password_and_errors(clock: SimulatedClock) -> None:
    """FoE: write/read with file name and password; a missing file gives 0x8001, a wrong password 0x800A."""
    files = FoeFiles(passwords={"secret.bin": 0x1234})
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    seg = Segment([create_io_slave(clock, foe=files)])
    m = Master(clock, seg)
    m.scan()
    m.request_state(0, AlState.PREOP)
    blob = bytes(range(256)) * 2 + b"x" * 116  # exactly 6 full 116-byte packets -> empty last packet
    m.foe_write(0, "secret.bin", blob, password=0x1234)
    assert files.files["secret.bin"] == blob
    assert m.foe_read(0, "secret.bin", password=0x1234) == blob
    with pytest.raises(FoeError) as err:
        m.foe_read(0, "nothing.bin")
    assert err.value.code == FoeErrorCode.NOT_FOUND
    with pytest.raises(FoeError) as err:
        m.foe_write(0, "secret.bin", b"x", password=1)
    assert err.value.code == FoeErrorCode.NO_RIGHTS


def test_state_machine_refusals(master: Master) -> None:
    """IDX 4.2 table 4-17 lists the legal transitions; ETG AL status codes for refused ones:
    0x0011 invalid requested state change, 0x0012 unknown state, 0x0013 bootstrap not supported."""
    with pytest.raises(AlStatusError) as err:
        master.request_state(0, AlState.OP)
    assert err.value.code == AlStatusCode.INVALID_STATE_CHANGE
    assert master.al_status(0) == (0x11, 0x0011)
    # Without acknowledge the error indication stays and higher requests are ignored.
    with pytest.raises(AlStatusError):
        master.request_state(0, AlState.PREOP)
    assert master.request_state(0, AlState.PREOP, ack=True) == AlState.PREOP
    assert master.al_status(0) == (0x02, 0)
    master.fpwr(master.slaves[1].station, 0x0120, b"\x05\x00")
    assert master.al_status(1) == (0x11, AlStatusCode.UNKNOWN_STATE)
    with pytest.raises(AlStatusError) as err:
        master.request_state(2, AlState.BOOT)
    assert err.value.code == AlStatusCode.BOOTSTRAP_NOT_SUPPORTED


def test_invalid_mailbox_and_sm_configuration_refused(master: Master) -> None:
    """INIT->PREOP needs the SII mailbox SMs (0x0016); PREOP->SAFEOP needs SM2/SM3 matching the
    mapping (0x001D invalid output configuration, 0x001E invalid input configuration)."""
    s = master.slaves[0]
    master.request_state(1, AlState.PREOP)
    master.request_state(2, AlState.PREOP)
    master.fpwr(s.station, REG_SM, bytes.fromhex("0010 4000 26 00 01 00".replace(" ", "")))
    master.fpwr(s.station, 0x0120, b"\x02\x00")
    assert master.al_status(0) == (0x11, AlStatusCode.INVALID_MAILBOX_CONFIG)
    master.request_state(0, AlState.PREOP, ack=True)
    master.config_map()
    master.fpwr(s.station, REG_SM + 16, bytes.fromhex("0011 0400 64 00 01 00".replace(" ", "")))
    with pytest.raises(AlStatusError) as err:
        master.request_state(0, AlState.SAFEOP)
    assert err.value.code == AlStatusCode.INVALID_OUTPUT_CONFIG
    master.config_map()
    master.fpwr(s.station, REG_SM + 24, bytes.fromhex("0014 0900 24 00 01 00".replace(" ", "")))
    with pytest.raises(AlStatusError) as err:
        master.request_state(0, AlState.SAFEOP, ack=True)
    assert err.value.code == AlStatusCode.INVALID_INPUT_CONFIG


def test_device_hook_refuses_and_sees_transitions(clock: SimulatedClock) -> None:
    """Devices refuse transitions with their own AL code and act on the ones that happen."""
    seen: list[tuple[AlState, AlState]] = []

    class Picky(SlaveApplication):
        def on_transition(self, slave: Slave, old: AlState, new: AlState) -> int:
            return AlStatusCode.NO_VALID_OUTPUTS if new == AlState.OP else 0

        def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
            seen.append((old, new))

    from gatewaylab.devices.ethercat_io.device import io_description
    m = Master(clock, Segment([Slave(clock, io_description(), Picky())]))
    m.scan()
    m.set_state(AlState.PREOP)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    with pytest.raises(AlStatusError) as err:
        m.set_state(AlState.OP)
    assert err.value.code == AlStatusCode.NO_VALID_OUTPUTS
    assert seen == [(AlState.INIT, AlState.PREOP), (AlState.PREOP, AlState.SAFEOP)]


def test_process_data_cycles_with_working_counter(master: Master, segment: Segment) -> None:
    """One LRW per cycle: outputs reach the devices (OP), inputs come back; WKC = 2*3 + 3."""
    master.set_state(AlState.PREOP)
    master.config_map()
    master.set_state(AlState.SAFEOP)
    master.pdo_write8(0, 0, 0x55)
    assert master.exchange_process_data() == 9
    assert segment.slaves[0].outputs == bytes(5)  # SAFEOP: setpoints ignored, safe values used
    master.set_state(AlState.OP)
    for i in range(1000):
        for pos in range(3):
            master.pdo_write8(pos, 0, (i + pos) & 0xFF)
            master.pdo_write16(pos, 1, i)
        assert master.exchange_process_data() == master.expected_wkc == 9
        assert master.pdo_read8(2, 0) == (i + 2) & 0xFF
    assert segment.slaves[1].read_output(0x7010, 1) == 999
    assert master.pdo_read16(1, 1) == 999
    assert master.pdo_read32(0, 5) == 1000


def test_cyclic_callback_and_sm_watchdog(master: Master, clock: SimulatedClock, segment: Segment) -> None:
    """QEC 3.5 cyclic callback on a 1 ms clock; when cycles stop, the SM watchdog (0x0400/0x0420:
    100 ms) takes the slaves to SAFEOP with AL status code 0x001B and the outputs to a safe state."""
    master.bring_up()
    calls: list[int] = []

    def cycle(m: Master) -> None:
        calls.append(m.last_wkc)
        m.pdo_write8(0, 0, 0xFF)

    master.start_cyclic(0.001, cycle)
    clock.advance(0.5)
    assert len(calls) == 500 and set(calls) == {9}
    assert segment.slaves[0].outputs[0] == 0xFF
    master.stop_cyclic()
    clock.advance(0.099)
    assert master.al_status(0) == (0x08, 0)
    clock.advance(0.002)
    assert [master.al_status(p) for p in range(3)] == [(0x14, AlStatusCode.SM_WATCHDOG)] * 3
    assert segment.slaves[0].outputs == bytes(5)


def test_sync0_events_reach_the_device(master: Master, clock: SimulatedClock, segment: Segment) -> None:
    """DC: SYNC0 cycle time 0x09A0, start time 0x0990, activation 0x0981 -> one event per cycle."""
    master.configure_sync0(0, 0.001, start_delay=0.01)
    clock.advance(0.0105)
    app = segment.slaves[0].app
    assert app.sync0_count == 1
    clock.advance(0.1)
    assert app.sync0_count == 101


def test_emergency_arrives_in_the_mailbox(master: Master, segment: Segment) -> None:
    """CoE emergency (service 1): error code, error register, 5 data bytes through SM1."""
    master.request_state(0, AlState.PREOP)
    segment.slaves[0].emergency(0x8130, 0x11, b"\x01\x02")
    s = master.slaves[0]
    raw = master.fprd(s.station, s.sii.mailbox_in[0], s.sii.mailbox_in[1])
    msg = decode_mailbox(raw)
    assert msg.type == MailboxType.COE and msg.data[1] >> 4 == CoeService.EMERGENCY
    assert msg.data[2:10] == bytes.fromhex("3081 11 0102000000".replace(" ", ""))


def test_foe_busy_then_ack(clock: SimulatedClock) -> None:
    """FoE BUSY: a slave that needs time (flashing) answers the last DATA packet with BUSY(done,
    entire); the master repeats that packet until the slave acknowledges it."""
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    from gatewaylab.ethercat.errors import FoeBusy

    class Flash:
        def __init__(self) -> None:
            self.ready_at = 0.05
            self.stored: bytes | None = None
            self.busy_answers = 0

        def foe_read(self, name: str, password: int) -> bytes:
            raise FoeError("write only", FoeErrorCode.ACCESS_DENIED)

        def foe_write(self, name: str, password: int, data: bytes) -> None:
            if clock.now() < self.ready_at:
                self.busy_answers += 1
                raise FoeBusy(int(100 * clock.now() / self.ready_at), 100)
            self.stored = data

    flash = Flash()
    m = Master(clock, Segment([create_io_slave(clock, foe=flash)]))
    m.scan()
    m.request_state(0, AlState.PREOP)
    m.foe_write(0, "firmware.bin", b"\x5a" * 300)
    assert flash.stored == b"\x5a" * 300 and flash.busy_answers >= 3
    with pytest.raises(FoeError) as err:
        m.foe_read(0, "firmware.bin")
    assert err.value.code == FoeErrorCode.ACCESS_DENIED


def test_bootstrap_allows_only_foe_with_the_bootstrap_mailbox(clock: SimulatedClock) -> None:
    """IDX 4.2 table 4-16 'Bootstrap: only FoE is possible (Mailbox), firmware download via FoE';
    table 4-17 IB/BI. The bootstrap mailbox (SII words 0x14..0x17) may be larger than the standard one."""
    import dataclasses

    from gatewaylab.devices.ethercat_io.device import IoApplication, io_description
    from gatewaylab.ethercat.errors import FrameFormatError
    desc = dataclasses.replace(io_description(), bootstrap=True, bootstrap_mailbox=(0x1000, 512, 0x1200, 512))
    files = FoeFiles()
    m = Master(clock, Segment([Slave(clock, desc, IoApplication(), files)]))
    m.scan()
    assert m.slaves[0].sii.bootstrap_mailbox == (0x1000, 512, 0x1200, 512)
    with pytest.raises(AlStatusError) as err:
        m.request_state(0, AlState.SAFEOP)
    assert err.value.code == AlStatusCode.INVALID_STATE_CHANGE
    assert m.request_state(0, AlState.BOOT, ack=True) == AlState.BOOT
    firmware = bytes(range(256)) * 8
    m.foe_write(0, "firmware.efw", firmware)
    assert files.files["firmware.efw"] == firmware
    with pytest.raises(FrameFormatError):
        m.sdo_upload32(0, 0x1018, 1)  # CoE in BOOT: mailbox error reply 'unsupported protocol'
    with pytest.raises(AlStatusError) as err:
        m.request_state(0, AlState.PREOP)
    assert err.value.code == AlStatusCode.INVALID_STATE_CHANGE  # BOOT -> PREOP is not a transition
    m.request_state(0, AlState.INIT, ack=True)
    m.request_state(0, AlState.PREOP)
    assert m.sdo_upload32(0, 0x1018, 1) == desc.vendor_id


def test_overlapping_sync_managers_refused(master: Master) -> None:
    """PREOP->SAFEOP with an SM overlapping the mailbox: AL status code 0x0017 invalid SM configuration."""
    master.set_state(AlState.PREOP)
    master.config_map()
    s = master.slaves[0]
    master.fpwr(s.station, REG_SM + 16, bytes.fromhex("4010 0500 64 00 01 00".replace(" ", "")))
    with pytest.raises(AlStatusError) as err:
        master.request_state(0, AlState.SAFEOP)
    assert err.value.code == AlStatusCode.INVALID_SM_CONFIG


def test_sdo_information_object_list_in_fragments(clock: SimulatedClock) -> None:
    """SDO Information answers longer than one mailbox are sent in fragments (fragments-left count
    down, 'incomplete' bit on all but the last)."""
    import dataclasses

    from gatewaylab.devices.ethercat_io.device import IoApplication, io_description
    from gatewaylab.ethercat.description import ObjectDef
    base = io_description()
    extra = tuple(ObjectDef(0x2000 + i, f"Parameter {i}", DataType.UNSIGNED16, i, Access.RW) for i in range(150))
    desc = dataclasses.replace(base, objects=base.objects + extra)
    m = Master(clock, Segment([Slave(clock, desc, IoApplication())]))
    m.scan()
    m.request_state(0, AlState.PREOP)
    indexes = m.od_list(0)
    assert len(indexes) == 19 + 150 and indexes[:3] == [0x1000, 0x1008, 0x1009]
    assert [i for i in indexes if 0x2000 <= i < 0x3000] == [0x2000 + i for i in range(150)]
    assert m.sdo_upload16(0, 0x2095) == 0x95


def test_slave_without_mailbox_uses_sm0_sm1_for_process_data(clock: SimulatedClock) -> None:
    """A simple I/O slave without CoE/FoE: no mailbox SMs, process data in SM0/SM1, sizes from the
    SII PDO/SM categories (shared notes: SOEM reads the PDO categories when there is no CoE)."""
    from gatewaylab.ethercat.description import DeviceDescription, Pdo, PdoEntry

    class Echo(SlaveApplication):
        def on_outputs(self, slave: Slave, data: bytes) -> None:
            slave.write_inputs(bytes([data[0] ^ 0xFF]))

    desc = DeviceDescription(name="GL-DIO 8", vendor_id=VENDOR_ID, product_code=0x00020001, coe=False, foe=False,
                             rx_pdos=(Pdo(0x1600, "Out", (PdoEntry(0x7000, 1, 8, "DO"),)),),
                             tx_pdos=(Pdo(0x1A00, "In", (PdoEntry(0x6000, 1, 8, "DI"),)),),
                             outputs_start=0x1000, inputs_start=0x1080)
    io = Slave(clock, desc, Echo())
    m = Master(clock, Segment([io]))
    m.bring_up()
    assert m.slaves[0].sii.mailbox_protocols == 0 and (m.slaves[0].output_bytes, m.slaves[0].input_bytes) == (1, 1)
    assert io.esc.sm_config(0).start == 0x1000 and io.esc.sm_config(1).start == 0x1080
    m.pdo_write8(0, 0, 0x0F)
    assert m.exchange_process_data() == 3
    assert io.outputs == b"\x0f" and m.pdo_read8(0, 0) == 0xF0


def test_device_fault_falls_back_with_error_and_needs_acknowledge(master: Master, segment: Segment) -> None:
    """A device error (e.g. CAN bus-off in a gateway) takes OP to SAFEOP with the error flag and an
    AL status code; IDX table 4-18: the master acknowledges with bit 4 before requesting OP again."""
    master.bring_up()
    segment.slaves[1].fault(AlStatusCode.SYNCHRONIZATION_ERROR)
    assert master.al_status(1) == (0x14, AlStatusCode.SYNCHRONIZATION_ERROR)
    assert segment.slaves[1].outputs == bytes(5)
    with pytest.raises(AlStatusError):
        master.request_state(1, AlState.OP)  # ignored without acknowledge
    assert master.request_state(1, AlState.OP, ack=True) == AlState.OP


def test_dynamic_pdo_assignment_and_images_larger_than_a_frame(clock: SimulatedClock,
                                                               chunked_description: DeviceDescription) -> None:
    """PDO assignment 0x1C12/0x1C13 selects the first N chunk PDOs (written in PREOP with sub 0 = 0
    first); 12 x 128 B per direction exceeds one datagram, so the master sends two LRW frames and
    the expected working counter counts the slave in each."""
    class Loop(SlaveApplication):
        def on_outputs(self, slave: Slave, data: bytes) -> None:
            slave.write_inputs(bytes(b ^ 0x5A for b in data))

    desc = chunked_description
    assert desc.output_bytes == 256
    m = Master(clock, Segment([Slave(clock, desc, Loop())]))
    m.scan()
    assert m.slaves[0].sii.sync_managers[2][1] == 256  # SII SM2 default size: two chunks
    m.set_state(AlState.PREOP)
    for assign, base in ((0x1C12, 0x1600), (0x1C13, 0x1A00)):
        m.sdo_download8(0, assign, 0, 0)
        for i in range(12):
            m.sdo_download16(0, assign, i + 1, base + i)
        m.sdo_download8(0, assign, 0, 12)
    assert m.config_map() == 2 * 12 * 128
    assert len(m.chunks) == 3 and m.expected_wkc == 2 + (2 + 1) + 1
    m.set_state(AlState.SAFEOP)
    m.exchange_process_data()
    m.set_state(AlState.OP)
    pattern = bytes(range(256)) * 6
    m.pdo_write(0, 0, pattern)
    assert m.exchange_process_data() == m.expected_wkc
    assert m.pdo_read(0, 0, 1536) == bytes(b ^ 0x5A for b in pattern)


def test_one_buffer_process_data_like_ecan_lite(clock: SimulatedClock,
                                                chunked_description: DeviceDescription) -> None:
    """ECAN-Lite manual 5.3: SM2 0x1100 / SM3 0x1D00, 3072 B, control bytes 0x66 / 0x22 (1-buffer
    handshake mode). The slave consumes each output buffer and refills its inputs every cycle, so
    every LRW gets the full working counter; the 48-PDO SII needs an EEPROM above 16 kbit."""
    import dataclasses

    class Loop(SlaveApplication):
        def on_outputs(self, slave: Slave, data: bytes) -> None:
            slave.write_inputs(data)

    desc = dataclasses.replace(chunked_description, outputs_control=0x66, inputs_control=0x22,
                               rx_assign=tuple(range(0x1600, 0x1618)), tx_assign=tuple(range(0x1A00, 0x1A18)))
    slave = Slave(clock, desc, Loop())
    assert len(slave.sii) > 2048 and slave.esc.mem[0x0502] & 0x80  # 'two address bytes'
    m = Master(clock, Segment([slave]))
    m.scan()
    assert [sm[:3] for sm in m.slaves[0].sii.sync_managers[2:]] == [(0x1100, 3072, 0x66), (0x1D00, 3072, 0x22)]
    m.set_state(AlState.PREOP)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    m.exchange_process_data()
    m.set_state(AlState.OP)
    for i in range(50):
        m.pdo_write(0, 0, bytes([i]) * 3072)
        assert m.exchange_process_data() == m.expected_wkc
        assert m.pdo_read(0, 3071, 1) == bytes([i])


def test_mapping_validation_and_refused_safeop(master: Master, segment: Segment) -> None:
    """QEC A.5: mapping a missing object, an object of the wrong direction or with the wrong length
    is refused with 0x06040041; assigning a missing PDO with 0x06090030. A mapping that still names a
    missing object (changed by the device) refuses PREOP->SAFEOP with 0x0024 / 0x0025."""
    master.set_state(AlState.PREOP)
    master.config_map()
    master.sdo_download8(0, 0x1A00, 0, 0)
    for bad in (0x5FFF0108, 0x70000108, 0x60000110):
        with pytest.raises(SdoAbort) as abort:
            master.sdo_download32(0, 0x1A00, 1, bad)
        assert abort.value.code == SdoAbortCode.OBJECT_NOT_MAPPABLE
    master.sdo_download32(0, 0x1A00, 1, 0x00000008)  # a gap is fine
    master.sdo_download8(0, 0x1C13, 0, 0)
    with pytest.raises(SdoAbort) as abort:
        master.sdo_download16(0, 0x1C13, 1, 0x1A05)
    assert abort.value.code == SdoAbortCode.VALUE_RANGE_EXCEEDED
    master.sdo_download8(0, 0x1C13, 0, 1)
    od = segment.slaves[0].od
    od.set(0x1A00, 1, 0x5FFF0108)  # the device itself put a broken mapping in place
    master.sdo_download8(0, 0x1A00, 0, 1)
    with pytest.raises(AlStatusError) as err:
        master.request_state(0, AlState.SAFEOP)
    assert err.value.code == AlStatusCode.INVALID_INPUT_MAPPING
    od.set(0x1A00, 1, 0x60000108)
    od.set(0x1600, 1, 0x5FFE0108)
    with pytest.raises(AlStatusError) as err:
        master.request_state(0, AlState.SAFEOP, ack=True)
    assert err.value.code == AlStatusCode.INVALID_OUTPUT_MAPPING
