"""One slave's faults (ec-al-error, ec-drop-state, ec-sdo-abort, ec-sdo-silent, ec-foe-error, ec-mailbox-lose,
ec-emcy, ec-eeprom) as the in-process master sees them, on a simulated clock (docs/faults.md).

ETG.1000.6 AL state machine: a refused transition sets the error flag (AL status 0x0130 bit 4) and the AL
status code (0x0134); only an acknowledge (AL control bit 4) clears it. ETG.1000.6 CoE: an SDO abort
carries its 32-bit code; an FoE error request (opcode 5) its error code. ETG.1000.4 mailbox: a reply
lost on the way back is repeated after the master toggles the repeat request (SM1 0x0806 bit 1) and the
ESC acknowledges it (0x0807 bit 1). ET1100 EEPROM interface 0x0502: busy bit 15, acknowledge error bit 13,
checksum error bit 11.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import pytest

from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.datagram import Command
from gatewaylab.ethercat.errors import AlStatusError, EtherCATConfigError, FoeError
from gatewaylab.ethercat.esc import REG_SM, AlState
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, decode_mailbox, encode_mailbox
from gatewaylab.ethercat.slave_faults import parse_transition
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import SdoAbort
from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[ethercat]
interface = "gl-none"
"""


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    with Rig.from_file(path) as r:
        r.start()
        yield r


def _master(rig: Rig) -> Master:
    segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
    master = Master(rig.clock, segment)
    master.bring_up()
    return master


def _board(rig: Rig) -> list[str]:
    return [f["fault"] for f in rig.faults.ethercat_states()["faults"]]


def test_transition_names() -> None:
    """ETG.1000.6 names transitions by the states' initials; the long form names both states."""
    assert parse_transition("ps") == (AlState.PREOP, AlState.SAFEOP)
    assert parse_transition("SAFEOP-OP") == (AlState.SAFEOP, AlState.OP)
    assert parse_transition("INIT>PREOP") == (AlState.INIT, AlState.PREOP)
    for bad in ("PP", "X", "PREOP-", "OP-OP"):
        with pytest.raises(EtherCATConfigError):
            parse_transition(bad)


def test_al_error_refuses_the_named_transition_until_acknowledged(rig: Rig) -> None:
    """ec-al-error io-b 0x001D --on PS: INIT->PREOP passes, PREOP->SAFEOP is refused with PREOP + error flag
    + 0x001D; a new request without acknowledge changes nothing (the flag is latched); the acknowledge
    clears it and the retry reaches SAFEOP (ETG.1000.6 AL control / AL status)."""
    m = _master(rig)
    m.set_state(AlState.INIT)
    answer = rig.faults.request({"fault": "ec-al-error", "device": "io-b", "code": 0x001D, "on": "PS"})
    assert answer["on"] == "PREOP-SAFEOP" and _board(rig) == ["ec-al-error"]
    m.request_state(1, AlState.PREOP)
    with pytest.raises(AlStatusError) as err:
        m.request_state(1, AlState.SAFEOP)
    assert err.value.code == 0x001D
    assert m.al_status(1) == (AlState.PREOP | 0x10, 0x001D)
    assert _board(rig) == []                                   # used up
    m.port.fpwr(m.slave(1).station, 0x0120, struct.pack("<H", AlState.SAFEOP))   # no acknowledge
    assert m.al_status(1) == (AlState.PREOP | 0x10, 0x001D)
    m.request_state(1, AlState.PREOP, ack=True)
    assert m.al_status(1) == (AlState.PREOP, 0)
    assert m.request_state(1, AlState.SAFEOP) == AlState.SAFEOP


def test_al_error_without_on_takes_the_next_transition_and_ec_clear_disarms(rig: Rig) -> None:
    m = _master(rig)
    rig.faults.ec_al_error("io-a", 0x0035)
    with pytest.raises(AlStatusError) as err:
        m.request_state(0, AlState.SAFEOP)                      # OP -> SAFEOP, the next one
    assert err.value.code == 0x0035
    rig.faults.ec_al_error("io-a", 0x0035, on="SO")
    assert rig.faults.ec_clear("io-a")["ended"][0]["fault"] == "ec-al-error"
    m.request_state(0, AlState.SAFEOP, ack=True)
    assert m.request_state(0, AlState.OP) == AlState.OP
    with pytest.raises(FaultRefused):
        rig.faults.ec_al_error("io-a", 0x0035, on="PX")


def test_drop_state_safeop_lowers_the_working_counter_and_the_master_recovers(rig: Rig) -> None:
    """ec-drop-state io-a SAFEOP: SAFEOP + error + 0x001B, the output SyncManager stops (its share of the
    LRW working counter is missing); acknowledge and OP again restore the full working counter."""
    m = _master(rig)
    full = m.exchange_process_data()
    answer = rig.faults.ec_drop_state("io-a", "SAFEOP")
    assert answer["code"] == 0x001B and answer["from"] == "OP"
    assert m.al_status(0) == (AlState.SAFEOP | 0x10, 0x001B)
    assert m.exchange_process_data() < full
    m.request_state(0, AlState.SAFEOP, ack=True)
    m.request_state(0, AlState.OP)
    assert m.exchange_process_data() == full
    with pytest.raises(FaultRefused):
        rig.faults.ec_drop_state("io-a", "OP")
    assert rig.faults.ec_drop_state("io-a", "PREOP", code=0x0021)["al_status"] == AlState.PREOP | 0x10


def test_drop_state_init_is_a_power_glitch(rig: Rig) -> None:
    """INIT without a code: the ESC powers on again (AL status INIT, no error, station address 0x0010
    lost: FPRD to it unanswered), as ethercat-replug does; with a code the registers stay."""
    m = _master(rig)
    station = m.slave(1).station
    answer = rig.faults.ec_drop_state("io-b", "INIT")
    assert answer["reset"] and answer["al_status"] == AlState.INIT
    assert m.port.phys(Command.FPRD, station, 0x0130, b"\0\0").wkc == 0
    d = m.port.phys(Command.APRD, -1, 0x0010, b"\0\0")
    assert d.wkc == 1 and d.data == b"\0\0"
    rig.faults.ec_drop_state("io-a", "INIT", code=0x0016)
    assert m.al_status(0) == (AlState.INIT | 0x10, 0x0016)


def test_sdo_abort_to_an_index_then_at_a_segment(rig: Rig) -> None:
    """ec-sdo-abort io-a 0x06020000 --index 0x8000: a read of 0x1018 passes, the read of 0x8000 aborts with
    the code; --segment 2: a 400-byte segmented download to 0x8000:01 gets its initiate and first segment
    answered, the second segment request is aborted (the value stays); so is an upload's; the next
    transfers work."""
    m = _master(rig)
    rig.faults.ec_sdo_abort("io-a", 0x06020000, index=0x8000)
    assert m.sdo_upload32(0, 0x1018, 1) == 0x47574C42
    with pytest.raises(SdoAbort) as err:
        m.sdo_upload(0, 0x8000, 1)
    assert err.value.code == 0x06020000 and _board(rig) == []
    before = m.sdo_upload(0, 0x8000, 1)
    text = bytes(range(32, 112)) * 5
    rig.faults.ec_sdo_abort("io-a", 0x08000020, index=0x8000, segment=2)
    with pytest.raises(SdoAbort) as err:
        m.sdo_download(0, 0x8000, 1, text)
    assert err.value.code == 0x08000020
    assert m.sdo_upload(0, 0x8000, 1) == before
    m.sdo_download(0, 0x8000, 1, text)
    rig.faults.ec_sdo_abort("io-a", 0x08000020, segment=2)
    with pytest.raises(SdoAbort) as err:
        m.sdo_upload(0, 0x8000, 1)
    assert err.value.code == 0x08000020
    assert m.sdo_upload(0, 0x8000, 1) == text


def test_sdo_silent_times_out_then_the_next_works(rig: Rig) -> None:
    m = _master(rig)
    rig.faults.ec_sdo_silent("io-a", n=1)
    with pytest.raises(TimeoutError_):
        m.sdo_upload32(0, 0x1018, 1)
    assert _board(rig) == []
    assert m.sdo_upload32(0, 0x1018, 1) == 0x47574C42


def test_foe_error_at_packet_k(rig: Rig) -> None:
    """A 3-packet write fails at packet 2 with the FoE error code; written again, it completes."""
    m = _master(rig)
    data = bytes(range(256)) * 2
    rig.faults.ec_foe_error("io-a", 0x8008, packet=2)
    with pytest.raises(FoeError) as err:
        m.foe_write(0, "fw.bin", data)
    assert err.value.code == 0x8008
    m.foe_write(0, "fw.bin", data)
    rig.faults.ec_foe_error("io-a", 0x8001, packet=1)
    with pytest.raises(FoeError) as err:
        m.foe_read(0, "fw.bin")
    assert err.value.code == 0x8001
    assert m.foe_read(0, "fw.bin") == data


def test_mailbox_lose_then_the_repeat_request_gets_the_reply(rig: Rig) -> None:
    """The SDO reply is read with working counter 0 (lost); SM1 is empty; the master toggles the repeat
    request (0x0806 bit 1), the ESC acknowledges (0x0807 bit 1) and the reply is there again."""
    m = _master(rig)
    s = m.slave(0)
    rig.faults.ec_mailbox_lose("io-a")
    mo, mos = s.mailbox_out
    mi, mis = s.mailbox_in
    request = encode_mailbox(MailboxMessage(MailboxType.COE, bytes.fromhex("0020") + bytes([0x40, 0x18, 0x10, 0x01])
                                            + bytes(4), counter=1))
    assert m.port.phys(Command.FPWR, s.station, mo, request.ljust(mos, b"\0")).wkc == 1
    assert m.port.fprd(s.station, REG_SM + 8 + 5, 1)[0] & 0x08
    lost = m.port.phys(Command.FPRD, s.station, mi, bytes(mis))
    assert lost.wkc == 0 and _board(rig) == []
    assert not m.port.fprd(s.station, REG_SM + 8 + 5, 1)[0] & 0x08
    act = m.port.fprd(s.station, REG_SM + 8 + 6, 1)[0]
    m.port.fpwr(s.station, REG_SM + 8 + 6, bytes([act ^ 0x02]))
    assert m.port.fprd(s.station, REG_SM + 8 + 7, 1)[0] & 0x02 == (act ^ 0x02) & 0x02
    assert m.port.fprd(s.station, REG_SM + 8 + 5, 1)[0] & 0x08
    again = m.port.phys(Command.FPRD, s.station, mi, bytes(mis))
    assert again.wkc == 1
    reply = decode_mailbox(again.data)
    assert reply.type == MailboxType.COE and struct.unpack_from("<I", reply.data, 6)[0] == 0x47574C42


def test_emcy_reaches_the_master(rig: Rig) -> None:
    m = _master(rig)
    answer = rig.faults.ec_emcy("io-b", 0x8110, register=0x11, data="0102030405")
    assert answer["data"] == "0102030405"
    assert m.receive_emergency(1) == (0x8110, 0x11, bytes([1, 2, 3, 4, 5]))
    with pytest.raises(FaultRefused):
        rig.faults.ec_emcy("io-b", 0x8110, data="00" * 6)


def _sii_status(m: Master, station: int) -> int:
    return int(struct.unpack("<H", m.fprd(station, 0x0502, 2))[0])


def test_eeprom_busy_holds_the_read_until_the_time_is_over(rig: Rig) -> None:
    """busy for 0.5 s: 0x0502 shows busy at once and after a read command; the read runs when it ends."""
    m = _master(rig)
    s = m.slave(0)
    answer = rig.faults.ec_eeprom("io-a", "busy", seconds=0.5)
    assert answer["ends_at"] == pytest.approx(rig.clock.now() + 0.5)
    assert _sii_status(m, s.station) & 0x8000
    m.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0100, 0x000A))
    assert _sii_status(m, s.station) & 0x8000
    rig.clock.advance(0.6)  # type: ignore[attr-defined]
    assert _sii_status(m, s.station) & 0xF800 == 0 and _board(rig) == []
    assert struct.unpack("<I", m.fprd(s.station, 0x0508, 4))[0] == 0x00010001


def test_eeprom_stuck_read_fails_when_cleared(rig: Rig) -> None:
    m = _master(rig)
    s = m.slave(0)
    rig.faults.ec_eeprom("io-a", "stuck")
    assert not _sii_status(m, s.station) & 0x8000            # only a read gets stuck
    m.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0100, 0x000A))
    rig.clock.advance(1.0)  # type: ignore[attr-defined]
    assert _sii_status(m, s.station) & 0x8000
    rig.faults.ec_clear("io-a")
    assert _sii_status(m, s.station) & 0xA000 == 0x2000       # not busy, acknowledge error
    assert m.sii_read8(s.station, 0x000A)[:4] == struct.pack("<I", 0x00010001)


def test_eeprom_checksum_and_wrong_product(rig: Rig) -> None:
    """checksum: word 7 no longer matches (0x0502 bit 11, a reload fails); product=0x1234: the identity a
    master reads from SII word 0x0A is wrong; ec-clear puts both back."""
    m = _master(rig)
    s = m.slave(1)
    rig.faults.ec_eeprom("io-b", "checksum")
    assert _sii_status(m, s.station) & 0x0800
    m.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0100, 0x000A))
    assert _sii_status(m, s.station) & 0x0800                 # a read does not clear the load's status
    assert struct.unpack("<I", m.fprd(s.station, 0x0508, 4))[0] == 0x00010001   # but reads the data
    m.fpwr(s.station, 0x0502, struct.pack("<H", 0))           # a NOP clears the error bits
    assert not _sii_status(m, s.station) & 0x0800
    m.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0400, 0))  # a reload fails again
    m.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0400, 0))
    assert _sii_status(m, s.station) & 0x0800
    with pytest.raises(FaultRefused):
        rig.faults.ec_eeprom("io-b", "product=0x1234")
    rig.faults.ec_clear("io-b")
    assert not _sii_status(m, s.station) & 0x0800
    answer = rig.faults.ec_eeprom("io-b", "product=0x1234")
    assert answer["was"] == 0x00010001
    assert m.scan()[1].product_code == 0x1234
    rig.faults.ec_clear()
    assert m.scan()[1].product_code == 0x00010001


def _wd(m: Master, position: int, divider: int | None, time: int) -> None:
    s = m.slave(position)
    if divider is not None:
        m.fpwr(s.station, 0x0400, struct.pack("<H", divider))
    m.fpwr(s.station, 0x0420, struct.pack("<H", time))


def test_sm_watchdog_follows_0x0400_and_0x0420_as_the_master_writes_them(rig: Rig) -> None:
    """ET1100 0x0400 (divider: one tick = (divider + 2) x 40 ns) and 0x0420 (process data watchdog time in
    ticks, 0 = off): io-a with 100 us ticks x 30 = 3 ms drops to SAFEOP + 0x001B between 2.5 and 3.5 ms
    without outputs; io-b with 0x0420 = 0 never does; a divider of 4998 (200 us ticks) doubles the time;
    a time written while in OP counts from then on."""
    clock = rig.clock
    m = _master(rig)
    m.set_state(AlState.SAFEOP)
    _wd(m, 0, 2498, 30)
    _wd(m, 1, None, 0)
    m.exchange_process_data()
    m.set_state(AlState.OP)
    m.exchange_process_data()
    clock.advance(0.0025)  # type: ignore[attr-defined]
    assert m.al_status(0) == (AlState.OP, 0)
    clock.advance(0.001)  # type: ignore[attr-defined]
    assert m.al_status(0) == (AlState.SAFEOP | 0x10, 0x001B)
    clock.advance(1.0)  # type: ignore[attr-defined]
    assert m.al_status(1) == (AlState.OP, 0)                    # 0x0420 = 0: off
    m.request_state(0, AlState.SAFEOP, ack=True)
    _wd(m, 0, 4998, 30)                                         # 6 ms
    m.request_state(0, AlState.OP)
    m.exchange_process_data()
    clock.advance(0.005)  # type: ignore[attr-defined]
    assert m.al_status(0) == (AlState.OP, 0)
    clock.advance(0.0015)  # type: ignore[attr-defined]
    assert m.al_status(0) == (AlState.SAFEOP | 0x10, 0x001B)
    _wd(m, 1, 2498, 20)                                         # io-b in OP: 2 ms from now
    clock.advance(0.0015)  # type: ignore[attr-defined]
    assert m.al_status(1) == (AlState.OP, 0)
    clock.advance(0.001)  # type: ignore[attr-defined]
    assert m.al_status(1) == (AlState.SAFEOP | 0x10, 0x001B)


def test_sdo_abort_of_a_complete_access(rig: Rig) -> None:
    """A complete-access upload of 0x1018 (ETG.1000.6 complete access) is an SDO request like any other."""
    m = _master(rig)
    whole = m.sdo_upload(0, 0x1018, 0, complete=True)
    rig.faults.ec_sdo_abort("io-a", 0x06010000, index=0x1018)
    with pytest.raises(SdoAbort) as err:
        m.sdo_upload(0, 0x1018, 0, complete=True)
    assert err.value.code == 0x06010000
    assert m.sdo_upload(0, 0x1018, 0, complete=True) == whole


def test_refusals_of_the_rig(rig: Rig) -> None:
    """Arguments out of range and a second fault of a kind a device already has are refused."""
    _master(rig)
    for call in (lambda: rig.faults.ec_al_error("io-a", 0x10000), lambda: rig.faults.ec_sdo_silent("io-a", 0),
                 lambda: rig.faults.ec_foe_error("io-a", 0x8000, 0), lambda: rig.faults.ec_eeprom("io-a", "hot"),
                 lambda: rig.faults.ec_emcy("nobody", 0x1000), lambda: rig.faults.ec_drop_state("io-a", "BOOT")):
        with pytest.raises(FaultRefused):
            call()
    rig.faults.ec_sdo_silent("io-a", 2)
    with pytest.raises(FaultRefused):
        rig.faults.ec_sdo_silent("io-a", 1)
    assert [f["n"] for f in rig.faults.ethercat_states()["faults"]] == [2]
