"""Golden datagrams and register-level behaviour of the emulated ESC (ET1100 register map)."""

from __future__ import annotations

import struct

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.ethercat.datagram import (
    Command,
    Datagram,
    Frame,
    decode_datagrams,
    decode_frame,
    encode_datagrams,
    encode_frame,
)
from gatewaylab.ethercat.errors import FrameFormatError, MailboxErrorCode
from gatewaylab.ethercat.esc import REG_SM, AlState
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, decode_mailbox, encode_mailbox
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master


def run(segment: Segment, *datagrams: Datagram) -> tuple[Datagram, ...]:
    buf = bytearray(encode_frame(Frame(datagrams)))
    assert segment.process(buf)
    return decode_frame(buf).datagrams


def phys(cmd: Command, adp: int, ado: int, data: bytes, index: int = 0) -> Datagram:
    return Datagram.physical(cmd, index, adp, ado, data)


def test_golden_aprd_frame_bytes() -> None:
    """ETG.1000.4 datagram: cmd, idx, ADP, ADO, len (11 bits) | C | M, IRQ, data, WKC; header type 1."""
    raw = encode_datagrams([phys(Command.APRD, 0, 0x0130, b"\0\0", 0x42)])
    assert raw.hex() == "0e10" + "01" + "42" + "0000" + "3001" + "0200" + "0000" + "0000" + "0000"
    two = encode_datagrams([phys(Command.BRD, 0, 0, b"\0\0"), Datagram(Command.LRW, 1, 0x10000, b"\xaa")])
    assert two[2 + 6:2 + 8] == struct.pack("<H", 2 | 0x8000)  # 'more datagrams' flag on the first
    assert decode_datagrams(two)[1] == Datagram(Command.LRW, 1, 0x10000, b"\xaa")


def test_golden_aprd_through_three_slaves(segment: Segment) -> None:
    """Auto-increment addressing: each slave increments ADP; the one that sees 0 answers (WKC 1).
    AL status after power on is INIT (IDX 4.2 table 4-16 'Power ON')."""
    back = run(segment, phys(Command.APRD, 0, 0x0130, b"\0\0", 0x42))[0]
    assert back.adp == 3 and back.wkc == 1 and back.data == b"\x01\x00"
    third = run(segment, phys(Command.APRD, -2, 0x0012, b"\0\0"))[0]
    assert third.adp == 1 and third.wkc == 1


def test_broadcast_commands_count_every_slave(segment: Segment) -> None:
    """BRD ORs all slaves' data and counts 3; BWR writes all; APRW swaps and counts read+write = 3."""
    brd = run(segment, phys(Command.BRD, 0, 0x0000, b"\0"))[0]
    assert brd.wkc == 3 and brd.data == b"\x11"
    assert run(segment, phys(Command.BWR, 0, 0x0420, struct.pack("<H", 500)))[0].wkc == 3
    assert all(struct.unpack_from("<H", s.esc.mem, 0x0420)[0] == 500 for s in segment.slaves)
    rw = run(segment, phys(Command.APRW, -1, 0x0420, struct.pack("<H", 7)))[0]
    assert rw.wkc == 3 and struct.unpack("<H", rw.data)[0] == 500
    assert struct.unpack_from("<H", segment.slaves[1].esc.mem, 0x0420)[0] == 7


def test_configured_address_and_armw(segment: Segment) -> None:
    """FPxx addresses the station address 0x0010; ARMW: the addressed slave reads, the others write."""
    for pos in range(3):
        run(segment, phys(Command.APWR, -pos, 0x0010, struct.pack("<H", 0x1001 + pos)))
    assert run(segment, phys(Command.FPRD, 0x1002, 0x0010, b"\0\0"))[0].data == b"\x02\x10"
    assert run(segment, phys(Command.FPRD, 0x2000, 0x0010, b"\0\0"))[0].wkc == 0
    armw = run(segment, phys(Command.ARMW, 0, 0x0910, bytes(8)))[0]
    assert armw.wkc == 3
    frmw = run(segment, phys(Command.FRMW, 0x1003, 0x0910, bytes(8)))[0]
    assert frmw.wkc == 3


def test_read_only_registers_keep_their_value(segment: Segment) -> None:
    """AL status 0x0130, DL status 0x0110 and the SM status / PDI control bytes are read-only to the
    master (shared notes pitfall 5: SOEM writes the whole 8-byte SM block)."""
    esc = segment.slaves[0].esc
    run(segment, phys(Command.APWR, 0, 0x0130, b"\x08\x00"))
    assert esc.al_state == AlState.INIT
    dl = bytes(esc.mem[0x0110:0x0112])
    run(segment, phys(Command.APWR, 0, 0x0110, b"\xff\xff"))
    assert bytes(esc.mem[0x0110:0x0112]) == dl
    run(segment, phys(Command.APWR, 0, REG_SM, bytes.fromhex("0010800026ff01ff")))
    assert esc.sm_status(0) == 0 and esc.mem[REG_SM + 7] == 0 and esc.sm_config(0).start == 0x1000


def test_dl_status_reports_the_line_topology(segment: Segment) -> None:
    """0x0110: port 0 communication (0x0200) everywhere; port 1 open (0x0800) except on the last slave."""
    status = [struct.unpack_from("<H", s.esc.mem, 0x0110)[0] for s in segment.slaves]
    assert all(v & 0x0200 for v in status)
    assert [bool(v & 0x0800) for v in status] == [True, True, False]


def test_bit_exact_fmmu_mapping(clock: SimulatedClock, segment: Segment) -> None:
    """An FMMU maps logical bits 3..6 of logical byte 0x20 to physical bits 1..4 of 0x1500."""
    fmmu = struct.pack("<IHBBHBBB3x", 0x20, 1, 3, 6, 0x1500, 1, 3, 1)
    run(segment, phys(Command.APWR, 0, 0x0600, fmmu))
    back = run(segment, Datagram(Command.LWR, 0, 0x20, bytes([0b0111_1000])))[0]
    assert back.wkc == 1
    assert segment.slaves[0].esc.mem[0x1500] == 0b0001_1110
    segment.slaves[0].esc.mem[0x1500] = 0b0000_1010  # bits 1 and 3 set -> logical bits 3 and 5
    lrd = run(segment, Datagram(Command.LRD, 0, 0x1F, bytes([0xFF, 0b1000_0001, 0xFF])))[0]
    assert lrd.wkc == 1
    assert lrd.data == bytes([0xFF, 0b1010_1001, 0xFF])  # bits outside the FMMU stay untouched
    lrw = run(segment, Datagram(Command.LRW, 0, 0x20, bytes([0b0000_1000])))[0]
    assert lrw.wkc == 3  # read (+1) and write (+2) through the same read/write FMMU
    assert segment.slaves[0].esc.mem[0x1500] == 0b0000_0010


def test_lrw_outside_any_fmmu_is_not_counted(segment: Segment) -> None:
    """A logical access that hits no FMMU of any slave leaves the working counter at 0 (ETG.1000.4
    logical addressing: only slaves whose FMMU maps the address take part)."""
    assert run(segment, Datagram(Command.LRW, 0, 0x9000, b"\x00\x00"))[0].wkc == 0


def test_mailbox_full_and_empty_accesses_are_refused(master: Master, segment: Segment) -> None:
    """Shared notes pitfall 5: reading an empty mailbox or writing a full one is refused (no WKC)."""
    master.request_state(0, AlState.PREOP)
    s = master.slaves[0]
    empty = run(segment, phys(Command.FPRD, s.station, 0x1080, b"\x5a" * 128))[0]
    assert empty.wkc == 0 and empty.data == b"\x5a" * 128
    segment.slaves[0].mailbox.handlers.clear()  # nobody reads SM0: keep the reply queue empty
    req = encode_mailbox(MailboxMessage(MailboxType.COE, b"\0\x20" + bytes(8), 1)).ljust(128, b"\0")
    assert run(segment, phys(Command.FPWR, s.station, 0x1000, req))[0].wkc == 1


def test_mailbox_repeat_request_and_counter(master: Master, segment: Segment) -> None:
    """Mailbox repeat: toggling SM1's repeat bit (0x080E bit 1) puts the last reply back, acknowledged
    in 0x080F bit 1; a request repeating the previous counter is not executed again."""
    master.request_state(0, AlState.PREOP)
    s = master.slaves[0]
    req = encode_mailbox(MailboxMessage(MailboxType.COE, bytes.fromhex("0020") + bytes.fromhex("4018100100000000"),
                                        3)).ljust(128, b"\0")
    assert run(segment, phys(Command.FPWR, s.station, 0x1000, req))[0].wkc == 1
    first = run(segment, phys(Command.FPRD, s.station, 0x1080, bytes(128)))[0]
    assert first.wkc == 1 and decode_mailbox(first.data).type == MailboxType.COE
    run(segment, phys(Command.FPWR, s.station, REG_SM + 8 + 6, b"\x03"))
    esc = segment.slaves[0].esc
    assert esc.mem[REG_SM + 8 + 7] & 0x02 and esc.mailbox_full(1)
    again = run(segment, phys(Command.FPRD, s.station, 0x1080, bytes(128)))[0]
    assert again.data == first.data
    assert run(segment, phys(Command.FPWR, s.station, 0x1000, req))[0].wkc == 1  # same counter 3
    assert segment.slaves[0].mailbox.stats.repeated == 1
    assert not esc.mailbox_full(1)


def test_unsupported_mailbox_protocol_gets_error_reply(master: Master, segment: Segment) -> None:
    """A mailbox type the slave does not speak (EoE) -> mailbox error reply, code 0x0002."""
    master.request_state(0, AlState.PREOP)
    s = master.slaves[0]
    req = encode_mailbox(MailboxMessage(MailboxType.EOE, b"\0" * 4, 1)).ljust(128, b"\0")
    run(segment, phys(Command.FPWR, s.station, 0x1000, req))
    reply = decode_mailbox(run(segment, phys(Command.FPRD, s.station, 0x1080, bytes(128)))[0].data)
    assert reply.type == MailboxType.ERROR
    assert struct.unpack("<HH", reply.data) == (0x0001, MailboxErrorCode.UNSUPPORTED_PROTOCOL)


def test_sii_interface_read_write_reload(master: Master, segment: Segment) -> None:
    """EEPROM interface 0x0502..0x050F: read command (8 bytes), write needs write enable (error bit 14
    otherwise), reload re-checks the configuration area checksum (error bit 11) and loads the alias."""
    s = master.slaves[0]
    raw = master.sii_read8(s.station, 0x0008)
    assert struct.unpack("<II", raw) == (s.vendor_id, s.product_code)
    master.fpwr(s.station, 0x0508, b"\x34\x12")
    master.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0200, 0x0004))
    assert struct.unpack("<H", master.fprd(s.station, 0x0502, 2))[0] & 0x4000
    assert master.sii_write(s.station, 0x0004, 0x1234) & 0x7800 == 0
    master.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0400, 0))
    assert struct.unpack("<H", master.fprd(s.station, 0x0502, 2))[0] & 0x0800  # checksum now wrong
    assert master.fprd(s.station, 0x0012, 2) == b"\0\0"
    esc = segment.slaves[0].esc
    from gatewaylab.ethercat.esc import sii_checksum
    master.sii_write(s.station, 0x0007, sii_checksum(bytes(esc.eeprom[:14])))
    master.fpwr(s.station, 0x0502, struct.pack("<HI", 0x0400, 0))
    assert struct.unpack("<H", master.fprd(s.station, 0x0502, 2))[0] & 0x7800 == 0
    assert master.fprd(s.station, 0x0012, 2) == b"\x34\x12"


@pytest.mark.parametrize("raw", [b"", b"\x0e", b"\x0e\x20" + bytes(14), b"\xff\x17" + bytes(20),
                                 b"\x0e\x10\x01\x00" + bytes(4)])
def test_malformed_payloads_raise_frame_format_error(raw: bytes) -> None:
    """Truncated headers, lengths past the payload and bad datagram chains are format errors, never
    crashes (ETG.1000.4 datagram header: cmd, idx, address, len/flags, irq, data, WKC)."""
    with pytest.raises(FrameFormatError):
        decode_datagrams(raw)


def test_malformed_frame_is_dropped_and_counted(segment: Segment) -> None:
    """A frame whose EtherCAT length exceeds the frame is not answered and slave 0's invalid-frame
    counter 0x0300 goes up (the real ESC forwards it with a broken FCS)."""
    buf = bytearray(encode_frame(Frame((phys(Command.BRD, 0, 0, b"\0\0"),))))
    buf[14] = 0xFF
    assert not segment.process(buf)
    assert segment.stats.bad_frames == 1 and segment.slaves[0].esc.mem[0x0300] == 1


def test_alias_addressing_only_when_enabled(segment: Segment) -> None:
    """Configured station alias 0x0012 answers FPxx only with DL control 0x0100 bit 24 set."""
    run(segment, phys(Command.APWR, -1, 0x0012, struct.pack("<H", 0x0777)))
    assert run(segment, phys(Command.FPRD, 0x0777, 0x0000, b"\0"))[0].wkc == 0
    run(segment, phys(Command.APWR, -1, 0x0100, struct.pack("<I", 0x01000001)))
    hit = run(segment, phys(Command.FPRD, 0x0777, 0x0012, b"\0\0"))[0]
    assert hit.wkc == 1 and hit.data == b"\x77\x07"


def test_nop_datagram_passes_untouched(segment: Segment) -> None:
    """NOP (command 0): no slave reads, writes, increments ADP or the working counter."""
    back = run(segment, phys(Command.NOP, 0, 0x0120, b"\x08\x00"))[0]
    assert back.adp == 0 and back.wkc == 0
    assert all(s.esc.al_state == AlState.INIT for s in segment.slaves)
