"""The EtherCAT CiA 402 drive under the in-process master on the simulated clock (ETG.6010,
ETG.1020, CiA 402 over CoE): bring-up, power state machine, CSP, remapping, sync modes, faults."""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET

import pytest
from ecdrive_testkit import CSP, CSV, RX, STATE_MASK, TX, Line, make_line

from gatewaylab.canopen.cia402 import PdsState
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.objects import build_object_dictionary
from gatewaylab.devices.ethercat_drive import PRODUCT_CODE, EthercatDrive, drive_description
from gatewaylab.devices.ethercat_io.device import VENDOR_ID
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError, SdoAbort, SdoAbortCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.esi import export_esi
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig


@pytest.fixture
def line() -> Line:
    return make_line(2)


def test_two_drives_reach_op_with_the_default_pdo_assignment(line: Line) -> None:
    """ETG.6010 'PDO assignment': without configuration a master reads RxPDO 0x1600 (0x6040, 0x607A,
    0x60FF, 0x6071, 0x6060) and TxPDO 0x1A00 (0x6041, 0x6064, 0x606C, 0x6077, 0x6061, 0x603F) from
    0x1C12 / 0x1C13 (ETG.1000.6 PDO configuration); both drives reach OP with the full working counter."""
    m = line.master
    for pos in (0, 1):
        assert m.al_status(pos)[0] & 0x0F == AlState.OP
        assert m.slave(pos).vendor_id == VENDOR_ID and m.slave(pos).product_code == PRODUCT_CODE
        assert (m.sdo_upload8(pos, 0x1C12, 0), m.sdo_upload16(pos, 0x1C12, 1)) == (1, 0x1600)
        assert (m.sdo_upload8(pos, 0x1C13, 0), m.sdo_upload16(pos, 0x1C13, 1)) == (1, 0x1A00)
        assert [m.sdo_upload32(pos, 0x1600, i) for i in range(1, m.sdo_upload8(pos, 0x1600, 0) + 1)] == [
            0x60400010, 0x607A0020, 0x60FF0020, 0x60710010, 0x60600008]
        assert [m.sdo_upload32(pos, 0x1A00, i) for i in range(1, m.sdo_upload8(pos, 0x1A00, 0) + 1)] == [
            0x60410010, 0x60640020, 0x606C0020, 0x60770010, 0x60610008, 0x603F0010]
        assert (m.slave(pos).output_bytes, m.slave(pos).input_bytes) == (RX.size, TX.size)
    assert line.cycle() == m.expected_wkc == 6


def test_dictionary_is_the_canopen_drives_rows_served_by_coe(line: Line) -> None:
    """One dictionary (issue 9): the slave serves the CANopen drive's CiA 402 rows, and axis 0's
    drive runs on the slave's dictionary itself, so a CoE upload returns what the drive published."""
    slave = line.drives[0].slave
    assert line.drives[0].drives[0].od is slave.od
    canopen = build_object_dictionary(1, 1)
    for index in (0x603F, 0x6040, 0x6041, 0x6060, 0x6064, 0x6065, 0x607A, 0x607D, 0x60FF, 0x6502):
        for sub, entry in canopen.objects[index].entries.items():
            mine = slave.od.entries[(index, sub)]
            assert (mine.data_type, mine.access, mine.pdo_mappable, mine.default) == (
                entry.data_type, entry.access, entry.pdo_mappable, entry.default)
    line.enable(0)
    line.outputs(0, 0x0F, target=1234)
    line.cycle(300)
    x = line.inputs(0)[1]
    assert abs(x - 1234) <= 10
    assert line.master.sdo_upload32(0, 0x6064) == x == line.drives[0].drives[0].od.get(0x6064)


def test_controlword_06_07_0f_reaches_operation_enabled(line: Line) -> None:
    """CiA 402 transitions 2, 3, 4 by controlword 0x06, 0x07, 0x0F through the RxPDO, read back in
    the TxPDO statusword (ready to switch on 0x21, switched on 0x23, operation enabled 0x27 under
    mask 0x6F); bit 9 'remote' while the slave is in OP (ETG.6010: the ESM replaces NMT)."""
    for pos in (0, 1):
        seen = line.enable(pos)
        assert [sw & STATE_MASK for sw in seen] == [0x21, 0x23, 0x27]
        assert all(sw & 0x0200 for sw in seen)
        assert line.drives[pos].drives[0].state is PdsState.OPERATION_ENABLED
        assert line.inputs(pos)[4] == CSP


def test_csp_ramp_for_2s_at_1khz_follows_within_the_following_error_window(line: Line) -> None:
    """CSP (CiA 402 mode 8): a ramp of targets every 1 ms for 2 s (20,000 inc/s); every cycle the
    actual position 0x6064 stays within the following error window 0x6065 of the last target, no
    fault and no warning (statusword bits 3, 7, 13), and it ends at the last target."""
    for pos in (0, 1):
        line.enable(pos)
    window = line.master.sdo_upload32(0, 0x6065)
    worst = 0
    for i in range(2000):
        for pos in (0, 1):
            line.outputs(pos, 0x0F, target=20 * i * (1 if pos == 0 else -1))
        line.cycle()
        for pos in (0, 1):
            sw, x, *_ = line.inputs(pos)
            assert not sw & 0x2088, hex(sw)
            worst = max(worst, abs(20 * i * (1 if pos == 0 else -1) - x))
    assert worst <= window
    line.cycle(200)
    assert abs(line.inputs(0)[1] - 20 * 1999) <= 10 and abs(line.inputs(1)[1] + 20 * 1999) <= 10


def test_remapped_pdo_set_written_in_preop() -> None:
    """ETG.1000.6 PDO configuration in PREOP: the fixed CSP PDOs 0x1601 / 0x1A01 assigned in 0x1C12 /
    0x1C13 (sub 0 = 0, entries, sub 0 = n), and 0x1600 remapped (sub 0 = 0 first, else 0x06010003 ...
    'cannot be written'); the image follows and the fixed PDOs stay read-only."""

    def remap(m: Master) -> None:
        with pytest.raises(SdoAbort):
            m.sdo_download32(0, 0x1601, 1, 0x60FF0020)        # fixed PDO: read-only mapping
        m.sdo_download8(0, 0x1C12, 0, 0)
        m.sdo_download16(0, 0x1C12, 1, 0x1601)
        m.sdo_download8(0, 0x1C12, 0, 1)
        m.sdo_download8(0, 0x1C13, 0, 0)
        m.sdo_download16(0, 0x1C13, 1, 0x1A01)
        m.sdo_download8(0, 0x1C13, 0, 1)
        with pytest.raises(SdoAbort) as exc:                   # sub 0 still 5
            m.sdo_download32(1, 0x1600, 1, 0x60400010)
        assert exc.value.code == SdoAbortCode.SUBINDEX_CANNOT_BE_WRITTEN
        m.sdo_download8(1, 0x1600, 0, 0)
        m.sdo_download32(1, 0x1600, 1, 0x60400010)
        m.sdo_download32(1, 0x1600, 2, 0x607A0020)
        m.sdo_download32(1, 0x1600, 3, 0x60B00020)           # position offset
        m.sdo_download8(1, 0x1600, 0, 3)

    line = make_line(2, preop_setup=remap)
    m = line.master
    assert [(m.slave(p).output_bytes, m.slave(p).input_bytes) for p in (0, 1)] == [(6, 6), (10, 15)]
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download8(0, 0x1C12, 0, 0)                      # OP: mapping is PREOP-only
    assert exc.value.code == 0x08000022
    m.pdo_write(1, 0, struct.pack("<Hii", 0x06, 0, 0))
    m.pdo_write(0, 0, struct.pack("<Hi", 0x06, 0))
    line.cycle(3)
    assert struct.unpack("<H", m.pdo_read(0, 0, 2))[0] & STATE_MASK == 0x21
    assert line.drives[1].drives[0].state is PdsState.READY_TO_SWITCH_ON


@pytest.mark.parametrize(("rx", "tx", "code"), [
    ((0x1600, 0x1601), (0x1A00,), AlStatusCode.INVALID_OUTPUT_MAPPING),
    ((0x1600,), (0x1A00, 0x1A02), AlStatusCode.INVALID_INPUT_MAPPING),
])
def test_bad_mapping_is_refused_at_safeop(rx: tuple[int, ...], tx: tuple[int, ...], code: int) -> None:
    """ETG.1000.6 table 'AL status codes': an object mapped twice (0x1600 and its alternative 0x1601
    both assigned) refuses PREOP -> SAFEOP with 0x0025 'invalid output mapping' / 0x0024 'invalid
    input mapping'; the slave stays in PREOP with the error flag."""
    clock = SimulatedClock()
    drive = EthercatDrive(clock, "d", serial=1)
    m = Master(clock, Segment([drive.slave]))
    m.scan()
    m.set_state(AlState.PREOP)
    for assign, pdos in ((0x1C12, rx), (0x1C13, tx)):
        m.sdo_download8(0, assign, 0, 0)
        for i, pdo in enumerate(pdos, start=1):
            m.sdo_download16(0, assign, i, pdo)
        m.sdo_download8(0, assign, 0, len(pdos))
    m.config_map()
    with pytest.raises(AlStatusError) as exc:
        m.set_state(AlState.SAFEOP)
    assert exc.value.code == code
    status, al_code = m.al_status(0)
    assert status == (AlState.PREOP | 0x10) and al_code == code


def test_sync_mode_follows_the_master(line: Line) -> None:
    """ETG.1020 0x1C32: SM-synchronous (1) when the master activates no SYNC0 (outputs drive the
    control period), 0x1C33:01 = 0x22 (SM2 event); supported modes 0x1C32:04 list free run, SM and
    DC SYNC0; the cycle time is 1 ms."""
    m = line.master
    assert m.sdo_upload16(0, 0x1C32, 1) == 1 and m.sdo_upload16(0, 0x1C33, 1) == 0x22
    assert m.sdo_upload16(0, 0x1C32, 4) & 0x07 == 0x07
    assert m.sdo_upload32(0, 0x1C32, 2) == 1_000_000
    assert m.sdo_upload32(0, 0x1C32, 5) <= 1_000_000


@pytest.mark.parametrize(("mode", "code"), [(3, AlStatusCode.SYNCMODE_NOT_SUPPORTED),
                                             (2, AlStatusCode.INVALID_DC_SYNC_CONFIG)])
def test_sync_mode_the_drive_cannot_run_is_refused(mode: int, code: int) -> None:
    """ETG.1020: 0x1C32:01 written in PREOP; DC SYNC1 (3) is not among the supported modes (0x0028
    'sync mode not supported'), DC SYNC0 (2) without SYNC0 activated in 0x0981 is 0x0030 'invalid
    DC SYNC configuration'."""
    clock = SimulatedClock()
    drive = EthercatDrive(clock, "d", serial=1)
    m = Master(clock, Segment([drive.slave]))
    m.scan()
    m.set_state(AlState.PREOP)
    m.sdo_download16(0, 0x1C32, 1, mode)
    m.config_map()
    with pytest.raises(AlStatusError) as exc:
        m.set_state(AlState.SAFEOP)
    assert exc.value.code == code


def test_free_run_written_by_the_master_runs_the_drive_without_frames() -> None:
    """ETG.1020 free run (0x1C32:01 = 0): the drive runs its own 1 ms cycle whatever the master's
    cycle; with frames every 10 ms for 0.5 s the axis moves 0.5 s worth in CSV (SM-synchronous
    would run one period per frame: 50 ms worth)."""

    def free(m: Master) -> None:
        m.sdo_download16(0, 0x1C32, 1, 0)

    line = make_line(1, preop_setup=free)
    assert line.master.sdo_upload16(0, 0x1C32, 1) == 0
    line.enable(0, mode=CSV)
    line.outputs(0, 0x0F, velocity=10_000, mode=CSV)
    line.cycle()
    before = line.drives[0].drives[0].plant.state.position
    line.cycle(50, period=0.01)
    assert line.drives[0].drives[0].plant.state.position - before > 3000


def test_dc_sync0_configured_by_the_master_samples_targets_at_sync0() -> None:
    """ETG.1020 DC SYNC0 mode: the master activates SYNC0 (0x0981, cycle 0x09A0 = 1 ms); the drive
    reports sync mode 2 and cycle time 1 ms in 0x1C32, and runs its control period at SYNC0: a
    set-point that arrives between two pulses is taken at the next pulse, not at its arrival."""
    line = make_line(1, dc=True)
    m = line.master
    assert m.sdo_upload16(0, 0x1C32, 1) == 2 and m.sdo_upload32(0, 0x1C32, 2) == 1_000_000
    line.enable(0)
    drive = line.drives[0].drives[0]
    esc = line.drives[0].slave.esc
    next_pulse = esc.sync0_next
    line.clock.run_until(next_pulse + 0.0003)                   # 0.3 ms after a pulse
    line.outputs(0, 0x0F, target=500)
    m.exchange_process_data()
    line.clock.run_until(next_pulse + 0.0009)
    assert drive.demand == 0                                    # arrived, not yet sampled
    line.clock.run_until(next_pulse + 0.0011)
    assert drive.demand == 500                                  # taken at the pulse


def test_dc_missed_cycles_are_counted_and_drop_the_drive_to_safeop() -> None:
    """ETG.1020 0x1C32:0B 'SM event missed': SYNC0 pulses without new outputs are counted; when the
    sync error counter passes 0x10F1:02 the drive sets 0x1C32:20 'sync error' and falls back to
    SAFEOP with AL status code 0x001A 'synchronization error' (ETG.1000.6 table 11)."""
    line = make_line(1, dc=True)
    m = line.master
    line.enable(0)
    line.cycle(20)
    assert m.sdo_upload16(0, 0x1C32, 11) == 0
    line.clock.advance(0.006)                                   # the master stops sending
    status, code = m.al_status(0)
    assert status == (AlState.SAFEOP | 0x10) and code == AlStatusCode.SYNCHRONIZATION_ERROR
    assert m.sdo_upload16(0, 0x1C32, 11) >= 2
    assert m.sdo_upload8(0, 0x1C32, 32) == 1
    m.request_state(0, AlState.SAFEOP, ack=True)                 # acknowledge, then up again
    m.set_state(AlState.OP)
    assert m.al_status(0)[0] & 0x0F == AlState.OP


def test_following_error_fault_is_an_emcy_and_fault_reset_clears_it(line: Line) -> None:
    """CiA 402 following error (0x6065 window, 0x6066 time out) -> fault reaction -> fault; 0x603F =
    0x8611 in the TxPDO and a CoE emergency (ETG.1000.6) with code 0x8611 and error register
    'generic + device profile'; fault reset (controlword bit 7 rising, transition 15) clears 0x603F,
    sends emergency 0x0000 and reaches 'switch on disabled'."""
    line.enable(0)
    line.outputs(0, 0x0F, target=200_000)                      # a jump the axis cannot follow
    line.cycle(300)
    sw, _x, _v, _t, _mode, err = line.inputs(0)
    assert sw & STATE_MASK == 0x08 and err == 0x8611
    assert line.master.receive_emergency(0) == (0x8611, 0x21, b"\x01\0\0\0\0")
    line.outputs(0, 0x80, target=0)
    line.cycle(3)
    sw, *_, err = line.inputs(0)
    assert sw & STATE_MASK == 0x40 and err == 0
    assert line.master.receive_emergency(0)[:2] == (0x0000, 0x00)
    assert line.master.sdo_upload16(0, 0x603F) == 0
    assert line.enable(0)[-1] & STATE_MASK == 0x27


def test_over_current_is_an_emcy(line: Line) -> None:
    """Over-current from the plant's limits: the motor torque held at 0x6072 longer than 0x2010 ms
    (a blocked axis in CSV) faults the drive with 0x603F = 0x2310 'continuous over current' and a
    CoE emergency with error register 'current + generic'."""
    line.master.sdo_download16(0, 0x2010, 0, 100)
    line.enable(0, mode=CSV)
    line.drives[0].drives[0].plant.external_torque = -50_000.0   # blocks the axis
    line.outputs(0, 0x0F, velocity=100_000, mode=CSV)
    line.cycle(400)
    sw, *_, err = line.inputs(0)
    assert sw & STATE_MASK == 0x08 and err == 0x2310
    assert line.master.receive_emergency(0)[:2] == (0x2310, 0x03)


def test_multi_axis_drive_has_its_axes_0x800_apart() -> None:
    """ETG.6010 multi-axis: axis n's objects at index + 0x800 n (0x6840 controlword of axis 2), its
    PDOs at 0x1600 + 0x10 n / 0x1A00 + 0x10 n, assigned by default one after the other; each axis
    runs its own CiA 402 state machine; CoE reads and writes of the offset rows reach that axis."""
    line = make_line(1, axes=2)
    m = line.master
    assert [m.sdo_upload16(0, 0x1C12, i) for i in (1, 2)] == [0x1610 - 0x10, 0x1610]
    assert m.sdo_upload32(0, 0x1610, 1) == 0x68400010 and m.sdo_upload32(0, 0x1A10, 2) == 0x68640020
    assert (m.slave(0).output_bytes, m.slave(0).input_bytes) == (2 * RX.size, 2 * TX.size)
    seen = line.enable(0, axis=1)
    assert [sw & STATE_MASK for sw in seen] == [0x21, 0x23, 0x27]
    drives = line.drives[0].drives
    assert drives[1].state is PdsState.OPERATION_ENABLED and drives[0].state is PdsState.SWITCH_ON_DISABLED
    assert m.sdo_upload16(0, 0x6841) == line.inputs(0, axis=1)[0]
    assert line.inputs(0, axis=0)[0] & STATE_MASK == 0x40
    m.sdo_download32(0, 0x6865, 0, 1234)                       # axis 2 following error window
    assert drives[1].od.get(0x6065) == 1234 and drives[0].od.get(0x6065) == 2000
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download8(0, 0x6898, 0, 99)                      # homing method axis 2: not supported
    assert exc.value.code == SdoAbortCode.VALUE_RANGE_EXCEEDED
    line.outputs(0, 0x0F, target=-777, axis=1)
    line.cycle(300)
    x = line.inputs(0, axis=1)[1]
    assert abs(x + 777) <= 10 and m.sdo_upload32(0, 0x6864) - (1 << 32) == x == drives[1].od.get(0x6064)
    assert line.inputs(0, axis=0)[1] == 0


def test_esi_lists_the_dc_op_modes_and_the_fixed_alternatives() -> None:
    """ETG.2000 ESI: <Dc> op modes Free Run, SM-Synchron and DC-Synchron (AssignActivate #x0300);
    the CSP / CSV PDOs are Fixed and exclude each other; profile 402 in <Profile>."""
    root = ET.fromstring(export_esi(drive_description(axes=2)))
    modes = [(m.findtext("Name"), m.findtext("AssignActivate")) for m in root.iter("OpMode")]
    assert modes == [("FreeRun", "#x0000"), ("SM", "#x0000"), ("DC", "#x0300")]
    rx = {p.findtext("Index"): p for p in root.iter("RxPdo")}
    assert rx["#x1601"].get("Fixed") == "1" and rx["#x1600"].get("Fixed") == "0"
    assert [e.text for e in rx["#x1600"].findall("Exclude")] == ["#x1601", "#x1602"]
    assert rx["#x1610"].get("Sm") == "2"
    assert root.find(".//Profile/ProfileNo") is not None and root.findtext(".//Profile/ProfileNo") == "402"


def test_rig_kind_joins_the_segment_and_the_ready_file() -> None:
    """Rig file: ``[[device]] kind = "ethercat_drive"`` with serial, axes and plant keys joins the
    [ethercat] segment in file order and is listed in the ready file's ethercat.slaves."""
    config = parse_rig({"clock": "simulated",
                        "device": [{"kind": "ethercat_drive", "name": "x1", "serial": 0x3001},
                                   {"kind": "ethercat_drive", "name": "x2", "axes": 2, "plant": {"kp": 80.0}}],
                        "ethercat": {"interface": "gl-none"}})
    with Rig(config) as rig:
        rig.start()
        slaves = rig.ready_info()["ethercat"]["slaves"]
        assert [(s["name"], s["product_code"]) for s in slaves] == [("x1", PRODUCT_CODE), ("x2", PRODUCT_CODE)]
        x2 = next(p for p in rig.participants if p.name == "x2")
        assert x2.device.drives[1].plant.params.kp == 80.0  # type: ignore[attr-defined]
    with pytest.raises(Exception, match="axes"):
        parse_rig({"clock": "simulated", "device": [{"kind": "ethercat_drive", "axes": 5}],
                   "ethercat": {"interface": "gl-none"}})


def test_leaving_op_disables_the_axis(line: Line) -> None:
    """Outputs leaving OP are the safe state (zeros, ETG.1000.6): the controlword 0 is 'disable
    voltage' (CiA 402 transition 9/12) and the statusword loses 'remote'."""
    line.enable(0)
    line.master.request_state(0, AlState.SAFEOP)
    line.clock.advance(0.01)
    assert line.drives[0].drives[0].state is PdsState.SWITCH_ON_DISABLED
    assert not line.master.sdo_upload16(0, 0x6041) & 0x0200


def test_profile_position_and_homing_through_coe_and_process_data(line: Line) -> None:
    """CiA 402 PP (mode 1) and HM (mode 6) as on CANopen, over EtherCAT: homing method 37 (0x6098
    by CoE) sets the home position 0x30B0 at once (statusword bits 10 + 12); a PP set-point
    (0x607A, controlword bit 4 rising) is acknowledged (bit 12) and reached (bit 10) in the window."""
    m = line.master
    m.sdo_download32(0, 0x30B0, 0, 1000)
    line.enable(0, mode=6)
    line.outputs(0, 0x1F, mode=6)                              # start homing
    line.cycle(3)
    sw, x, *_ = line.inputs(0)
    assert sw & 0x1400 == 0x1400 and abs(x - 1000) <= 1
    line.outputs(0, 0x0F, target=5000, mode=1)                 # PP, bit 4 low
    line.cycle(2)
    line.outputs(0, 0x1F, target=5000, mode=1)                 # new set-point
    line.cycle(2)
    assert line.inputs(0)[0] & 0x1000                          # set-point acknowledge
    line.outputs(0, 0x0F, target=5000, mode=1)
    line.cycle(800)
    sw, x, *_ = line.inputs(0)
    assert sw & 0x0400 and abs(x - 5000) <= m.sdo_upload32(0, 0x6067)
    assert line.inputs(0)[4] == 1
