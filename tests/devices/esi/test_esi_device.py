"""``kind = "esi"``: EtherCAT slaves from ESI files (ETG.2000), in process on a simulated clock.

The test files in ``data/`` are written here, modelled on real terminals (EL1008 8 DI, EL2008 8 DO, EL1859
8 DI + 8 DO, EL3102 2 AI with a CoE dictionary): identity, process data layout, dictionary. A master (the
in-process one, gatewaylab/hosts/ethercat/master.py) scans, maps and runs them as it runs any slave.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Iterator
from pathlib import Path

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esi.device import esi_slave
from gatewaylab.devices.esi.reader import EsiError, read_esi, read_esi_file
from gatewaylab.ethercat.errors import AlStatusError, FrameFormatError, MailboxErrorCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.mailbox import MailboxType
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.sii import Category, parse_sii
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import SdoAbort, SdoAbortCode
from gatewaylab.rig.runtime import Rig

DATA = Path(__file__).with_name("data")
DIGITAL = DATA / "GL-test-EL1xxx-EL2xxx.xml"
ANALOG = DATA / "GL-test-EL3102.xml"

RIG = f"""
clock = "simulated"

[[device]]
kind = "esi"
esi = "{DIGITAL}"
type = "EL2008"

[[device]]
kind = "esi"
esi = "{DIGITAL}"
type = "EL1008"
serial = 0x1008

[[device]]
kind = "esi"
esi = "{DIGITAL}"
type = "EL1859"
name = "dio"
[device.behaviour]
{chr(10).join(f'"0x{0x6000 + 0x10 * i:04X}:01" = {{ echo = "0x{0x7000 + 0x10 * i:04X}:01" }}' for i in range(8))}

[[device]]
kind = "esi"
esi = "GL-test-EL3102.xml"
name = "ai"
[device.behaviour]
"0x6000:11" = {{ sine = {{ amplitude = 10000, period = 0.1 }} }}
"0x6010:11" = "counter"

[ethercat]
interface = "gl-none"
"""


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[Rig, SimulatedClock, Segment]]:
    (tmp_path / "GL-test-EL3102.xml").write_bytes(ANALOG.read_bytes())   # relative to the rig file's folder
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    r = Rig.from_file(path)
    r.start()
    segment = next(p for p in r.participants if getattr(p, "name", "") == "ethercat").segment  # type: ignore[attr-defined]
    assert isinstance(r.clock, SimulatedClock)
    try:
        yield r, r.clock, segment
    finally:
        r.close()


def test_identity_and_sii_from_the_esi(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """ETG.2010 SII words 0x08..0x0F: vendor, product code, revision, serial (the rig's); the General
    category's name string is the ESI <Name>; SyncManager category from the ESI <Sm> rows (EL3102: mailbox
    SMs 0x1000/0x1080, 128 bytes, inputs 8 bytes at 0x1180); mailbox protocols word 0x1C: EoE 0x02, CoE 0x04,
    SoE 0x10 as the ESI <Mailbox> declares them."""
    _rig, clock, segment = rig
    m = Master(clock, segment)
    infos = m.scan()
    assert [(s.sii.vendor_id, s.sii.product_code, s.sii.revision) for s in infos] == [
        (2, 0x07D83052, 0x00100000), (2, 0x03F03052, 0x00100000), (2, 0x07433052, 0x00100000),
        (2, 0x0C1E3052, 0x00140000)]
    assert infos[1].sii.serial == 0x1008
    assert infos[0].sii.name == "EL2008 8K. Dig. Ausgang 24V, 0.5A (test model)"
    ai = infos[3].sii
    assert ai.mailbox_out == (0x1000, 128) and ai.mailbox_in == (0x1080, 128)
    assert ai.mailbox_protocols == 0x02 | 0x04 | 0x10
    assert [sm[:2] for sm in ai.sync_managers] == [(0x1000, 128), (0x1080, 128), (0x1100, 0), (0x1180, 8)]
    assert Category.TXPDO in ai.categories and Category.RXPDO not in ai.categories


def test_to_op_echo_and_sine_without_code(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """PREOP, mapping, SAFEOP, OP with the expected working counter; the EL1859's inputs echo its outputs
    (rules run on the outputs SM event, so the same LRW reads the echo); the EL3102's channel 1 value draws
    the sine (amplitude 10000, 0.1 s) and channel 2 counts one per cycle. The EL2008's and the EL1859's
    outputs SyncManager (SM0) runs where their ESI puts it, on the ESC's Digital I/O Output Data register
    0x0F00 (ET1100 data sheet II), so the echo's outputs come from there."""
    _rig, clock, segment = rig
    m = Master(clock, segment)
    m.bring_up()
    for do in (segment.slaves[0], segment.slaves[2]):
        assert do.esc.sm_config(0).start == 0x0F00 and do.esc.sm_active(0)
    # image: outputs EL2008 (1 byte), EL1859 (1 byte); inputs EL1008 (1), EL1859 (1), EL3102 (8)
    assert m.outputs_size == 2
    dio_out, dio_in, ai_in = 1, 2 + 1, 2 + 2
    values = []
    for cycle in range(120):
        pattern = (cycle * 37) & 0xFF
        m.image[dio_out] = pattern
        clock.advance(0.001)
        assert m.exchange_process_data() == m.expected_wkc
        assert m.image[dio_in] == pattern, cycle
        value = struct.unpack_from("<h", m.image, ai_in + 2)[0]
        values.append(value)
    # the rule runs once per cycle on the rig's clock (at the inputs read: a device without outputs)
    assert max(values) > 9000 and min(values) < -9000 and max(abs(v) for v in values) <= 10000
    assert sum(a != b for a, b in itertools.pairwise(values)) > 100
    c1 = struct.unpack_from("<h", m.image, ai_in + 6)[0]
    clock.advance(0.001)
    m.exchange_process_data()
    assert struct.unpack_from("<h", m.image, ai_in + 6)[0] == c1 + 1


def test_el2008_outputs_stored_in_their_objects(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """Without rules, outputs are stored into their mapped objects (BOOL entries, one bit each)."""
    _r, clock, segment = rig
    m = Master(clock, segment)
    m.bring_up()
    m.image[0] = 0b1010_0101
    clock.advance(0.001)
    m.exchange_process_data()
    od = segment.slaves[0].od
    assert [int(od.get(0x7000 + 0x10 * i, 1)) for i in range(8)] == [1, 0, 1, 0, 0, 1, 0, 1]


def test_coe_dictionary_from_the_esi(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """<Profile><Dictionary>: defaults (DefaultData little-endian, DefaultString), records with gaps in the
    subindexes (0x8000: 1, 6, 17, 18, 21), arrays (0x1C13 two elements), access (0x1018 ro: abort
    0x06010002), SDO information lists the ESI's objects (ETG.1000.6 SDO information)."""
    _rig, clock, segment = rig
    m = Master(clock, segment)
    m.scan()
    m.request_state(3, AlState.PREOP)
    assert m.sdo_upload_str(3, 0x1008) == "EL3102"
    assert m.sdo_upload32(3, 0x1000) == 0x01391389
    assert m.sdo_upload32(3, 0x8000, 18) == 65536
    assert [m.sdo_upload16(3, 0x1C13, i) for i in (1, 2)] == [0x1A00, 0x1A02]
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download32(3, 0x1018, 1, 5)
    assert exc.value.code == SdoAbortCode.READ_ONLY
    listed = m.od_list(3)
    assert {0x1000, 0x1018, 0x1A00, 0x1A03, 0x1C12, 0x1C13, 0x6000, 0x6010, 0x8000, 0x8010} <= set(listed)
    desc = m.object_description(3, 0x8000)
    assert (desc.name, desc.max_subindex) == ("AI Settings Ch.1", 21)
    entry = m.entry_description(3, 0x6000, 17)
    assert (entry.name, entry.data_type, entry.bit_length) == ("Value", 0x03, 16)
    assert entry.access & 0x80   # TxPDO mappable (ESI PdoMapping T)


def test_pdo_assignment_over_coe_checked(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """ETG.1000.6 PDO assignment in PREOP: 0x1C13 sub 0 = 0, entries, sub 0 = n. The compact PDOs
    (0x1A01/0x1A03, 2 bytes each) give a 4-byte inputs image; assigning more than the inputs SyncManager's
    MaxSize (8 bytes) aborts 0x06040042; a fixed PDO's mapping is read-only (0x06010002); in SAFEOP the
    assignment is refused with 0x08000022 (writable in PREOP only)."""
    _rig, clock, segment = rig
    m = Master(clock, segment)
    m.scan()
    for p in range(4):
        m.request_state(p, AlState.PREOP)
    m.sdo_download8(3, 0x1C13, 0, 0)
    m.sdo_download16(3, 0x1C13, 1, 0x1A00)
    m.sdo_download16(3, 0x1C13, 2, 0x1A01)
    m.sdo_download16(3, 0x1C13, 3, 0x1A02)
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download8(3, 0x1C13, 0, 3)
    assert exc.value.code == SdoAbortCode.PDO_LENGTH_EXCEEDED
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download32(3, 0x1A00, 1, 0x60000101)
    assert exc.value.code in (SdoAbortCode.READ_ONLY, SdoAbortCode.SUBINDEX_CANNOT_BE_WRITTEN)
    m.sdo_download16(3, 0x1C13, 1, 0x1A01)
    m.sdo_download16(3, 0x1C13, 2, 0x1A03)
    m.sdo_download8(3, 0x1C13, 0, 2)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    assert segment.slaves[3].input_bytes == 4
    with pytest.raises(SdoAbort) as exc:
        m.sdo_download8(3, 0x1C13, 0, 0)
    assert exc.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE


def test_declared_but_not_emulated_protocol_answers_unsupported(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """ETG.1000.4 mailbox error reply (type 0x00, service 0x01, detail 0x0002 'protocol not supported') for
    an EoE or SoE request the ESI declares but gatewaylab does not emulate: never silence."""
    _rig, clock, segment = rig
    m = Master(clock, segment)
    m.scan()
    m.request_state(3, AlState.PREOP)
    expected = struct.pack("<HH", 0x0001, MailboxErrorCode.UNSUPPORTED_PROTOCOL).hex()
    for mtype in (MailboxType.EOE, MailboxType.SOE):
        with pytest.raises(FrameFormatError, match=f"mailbox error reply {expected}"):
            m.mailbox_exchange(3, mtype, b"\x00" * 10)
    assert m.sdo_upload_str(3, 0x1008) == "EL3102"      # the mailbox carries on


# ------------------------------------------------------------------------------------------ files
def test_several_devices_need_a_type() -> None:
    with pytest.raises(EsiError, match=r"GL-test-EL1xxx-EL2xxx.xml: Descriptions/Devices: 3 devices match"):
        read_esi_file(DIGITAL)
    assert read_esi_file(DIGITAL, product_code=0x03F03052).type_name == "EL1008"


def _run_rig(tmp_path: Path, device: str) -> tuple[int, str]:
    import subprocess
    import sys
    (tmp_path / "rig.toml").write_text(f'clock = "simulated"\n[[device]]\nkind = "esi"\n{device}\n'
                                       '[ethercat]\ninterface = "gl-none"\n')
    done = subprocess.run([sys.executable, "-m", "gatewaylab", "run", str(tmp_path / "rig.toml")],
                          capture_output=True, text=True, timeout=120, check=False)
    return done.returncode, done.stderr.strip()


BAD = {
    "malformed": ('<EtherCATInfo><Vendor><Id>2</Id></Vendor>\n<Descriptions></Vendor>', "line 2 column"),
    "type": (DIGITAL.read_text(), "no device with type 'EL9999'"),
}


@pytest.mark.parametrize("case", ["malformed", "type", "pdo"])
def test_bad_files_one_line_exit_2(tmp_path: Path, case: str) -> None:
    """A bad file: one line naming the file, the element (or line) and what is wrong; exit 2."""
    if case == "pdo":
        text = ANALOG.read_text().replace('DefaultSize="8" Enable="1" MaxSize="8"',
                                          'DefaultSize="4" Enable="1" MaxSize="4"')
        expect = "Device 'EL3102' TxPdo: the assigned PDOs map 64 bits, more than <Sm>Inputs</Sm> holds (32 bits)"
        typ = ""
    else:
        text, expect = BAD[case]
        typ = 'type = "EL9999"' if case == "type" else ""
    (tmp_path / "bad.xml").write_text(text)
    code, err = _run_rig(tmp_path, f'esi = "bad.xml"\n{typ}')
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "bad.xml" in lines[0] and expect in lines[0], lines[0]


def test_sii_byte_for_byte_from_eeprom_data_or_a_dump(tmp_path: Path) -> None:
    """<Eeprom><Data> is the SII as it is (ETG.2000 Eeprom/Data); a ``sii`` dump wins over both."""
    clock = SimulatedClock()
    generated = esi_slave(clock, read_esi_file(DIGITAL, "EL1008"), "a").sii
    image = bytearray(generated)
    image[0x80 + 10:0x80 + 14] = b"ABCD"       # somewhere in the strings: not what the ESI would generate
    text = DIGITAL.read_text().replace("<ByteSize>2048</ByteSize>", f"<Data>{image.hex()}</Data>", 1)
    device = read_esi(text, "with-data.xml", "EL1008")
    assert esi_slave(clock, device, "b").sii == bytes(image)
    dump = tmp_path / "dump.bin"
    dump.write_bytes(generated)
    assert esi_slave(clock, device, "c", sii_path=dump).sii == generated
    assert parse_sii(generated).product_code == 0x03F03052


def test_rule_on_a_missing_entry_is_a_config_error(tmp_path: Path) -> None:
    code, err = _run_rig(tmp_path, f'esi = "{DIGITAL}"\ntype = "EL1008"\n[device.behaviour]\n"0x6000:02" = "counter"')
    assert code == 2 and "0x6000:02" in err and "no such entry" in err, err


def test_no_dictionary_gets_the_generic_one() -> None:
    """A device without <Dictionary>: identity (0x1018), PDO mapping/assignment objects and one object per
    mapped entry, so rules and reads find them."""
    slave = esi_slave(SimulatedClock(), read_esi_file(DIGITAL, "EL1859"), "x")
    od = slave.od
    assert od.get(0x1018, 2) == 0x07433052
    assert {0x1600, 0x1607, 0x1A00, 0x1A07, 0x1C12, 0x1C13} <= set(od.objects)
    assert od.entry(0x6070, 1).tx_pdo and od.entry(0x7070, 1).rx_pdo


def test_state_machine_refuses_wrong_sync_managers(rig: tuple[Rig, SimulatedClock, Segment]) -> None:
    """AL state machine as for every slave: PREOP with a mailbox SM that is not the SII's is refused
    (AL status code 0x0016 invalid mailbox configuration)."""
    _rig, clock, segment = rig
    m = Master(clock, segment)
    m.scan()
    m.fpwr(m.slave(3).station, 0x0800, struct.pack("<HHBBBB", 0x1000, 64, 0x26, 0, 1, 0))
    m.fpwr(m.slave(3).station, 0x0120, b"\x02\x00")
    status, code = m.al_status(3)
    assert status & 0x10 and code == 0x0016


def test_rules_run_once_per_cycle_and_the_hook_after_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A slave with outputs runs its rules on the outputs event only: a BOOL counter (+1 wraps 0/1) flips at
    every cycle (twice per cycle would keep it still); the hook runs after the rules with the values and the
    rig's time."""
    (tmp_path / "esi_test_hook.py").write_text(
        "def run(values, t):\n"
        "    values.set(0x6010, 1, 1 - int(values.get(0x6000, 1)))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "rig.toml").write_text(f'''clock = "simulated"
[[device]]
kind = "esi"
esi = "{DIGITAL}"
type = "EL1859"
hook = "esi_test_hook:run"
[device.behaviour]
"0x6000:01" = "counter"
[ethercat]
interface = "gl-none"
''')
    r = Rig.from_file(tmp_path / "rig.toml")
    r.start()
    try:
        segment = next(p for p in r.participants if getattr(p, "name", "") == "ethercat").segment  # type: ignore[attr-defined]
        clock = r.clock
        assert isinstance(clock, SimulatedClock)
        m = Master(clock, segment)
        m.bring_up()
        seen = []
        for _ in range(10):
            clock.advance(0.001)
            assert m.exchange_process_data() == m.expected_wkc
            seen.append(m.image[1] & 0x03)
        assert all(a != b for a, b in itertools.pairwise(seen)), seen
        assert all(v in (0b01, 0b10) for v in seen), seen    # channel 2 = not channel 1 (the hook)
    finally:
        r.close()


def test_an_inputs_sm_on_the_registers_stays_where_the_file_says_and_is_refused() -> None:
    """Only a buffered output SyncManager inside 0x0F00:0x0F03 (the Digital I/O Output Data register, ET1100
    data sheet II) runs below the process RAM: an EL1008 whose file put its inputs at 0x0F00 keeps them there
    (its SII says 0x0F00, the reader notes once that the ESC refuses it), and a master programming that
    SyncManager from the SII is refused SAFEOP with AL status code 0x0017 (invalid SyncManager configuration,
    ETG.1000.6), as a real ESC would refuse it; nothing is moved."""
    text = DIGITAL.read_text()
    el1008 = text.index(">EL1008<")
    old = 'StartAddress="#x1000">Inputs</Sm>'
    at = text.index(old, el1008)
    device = read_esi(text[:at] + old.replace("#x1000", "#x0f00") + text[at + len(old):], "moved.xml", "EL1008")
    assert device.desc.inputs_start == 0x0F00
    assert device.notes == ("Sm Inputs at 0x0F00 lies on the ESC registers: the ESC refuses it "
                            "(AL status 0x0017 at PREOP -> SAFEOP)",)
    clock = SimulatedClock()
    slave = esi_slave(clock, device, "di")
    m = Master(clock, Segment([slave]))
    info = m.scan()[0]
    assert info.sii.sync_managers[0][:2] == (0x0F00, 1)
    m.set_state(AlState.PREOP)
    m.fpwr(info.station, 0x0800, struct.pack("<HHBBBB", 0x0F00, 1, 0x00, 0, 1, 0))
    with pytest.raises(AlStatusError):
        m.request_state(0, AlState.SAFEOP)
    assert m.al_status(0) == (AlState.PREOP | 0x10, 0x0017)
