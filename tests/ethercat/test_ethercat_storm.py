"""Storms of random and malformed EtherCAT frames against the sans-I/O segment (issue 15: 'A malformed
EtherCAT frame kills the segment'): every datagram is processed or ignored, nothing raises, the ESC
memory keeps its size, and a master re-initialises the segment and reaches OP afterwards."""

from __future__ import annotations

import struct

from ethercat_storm import ETH, storm
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.errors import FrameFormatError
from gatewaylab.ethercat.esc import REG_AL_CONTROL, REG_SM, AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

VALID_STATES = {int(s) for s in AlState}
#: Most a datagram's working counter can grow per slave: read +1, write +2 (ETG.1000.4 'Working counter').
MAX_WKC_PER_SLAVE = 3


def fresh(n: int = 3) -> tuple[SimulatedClock, Segment]:
    clock = SimulatedClock()
    return clock, Segment([create_io_slave(clock, f"S{i}", serial=i, revision=i + 1) for i in range(n)])


def lrw(laddr: int, data: bytes) -> bytearray:
    return bytearray(encode_frame(Frame((Datagram(Command.LRW, 0, laddr, data),))))


def test_bitwise_fmmu_reaching_past_process_ram_is_processed() -> None:
    """The storm's crash (issue 15): a bit-wise FMMU (start bit 1) whose physical end lies past process
    RAM made ``Esc._fmmu_write`` raise IndexError. ET1100: accesses to non-existent memory are ignored;
    the datagram is processed (FMMU hit: LRW WKC +1 read +2 write) and the slave keeps working."""
    _clock, seg = fresh(1)
    esc = seg.slaves[0].esc
    end = len(esc.mem)
    fmmu = struct.pack("<IHBBHBBB3x", 0, 2, 1, 7, end - 1, 0, 3, 1)
    bwr = bytearray(encode_frame(Frame((Datagram.physical(Command.BWR, 0, 0, 0x0600, fmmu),))))
    assert seg.process(bwr)
    frame = lrw(0, b"\xff\xff")
    assert seg.process(frame)
    assert decode_frame(frame).datagrams[0].wkc == 3
    assert len(esc.mem) == end
    frame = lrw(0, b"\x00\x00")  # the next frame is served as well
    assert seg.process(frame) and decode_frame(frame).datagrams[0].wkc == 3


def test_mailbox_sm_past_process_ram_never_grows_memory() -> None:
    """A SyncManager the master put at the end of RAM (or beyond): the ESC has no memory there, so the
    mailbox put by the firmware is cut, never appended (ET1100: non-existent memory is not written)."""
    _clock, seg = fresh(1)
    esc = seg.slaves[0].esc
    end = len(esc.mem)
    sm1 = struct.pack("<HHBBBB", end - 4, 128, 0x02, 0, 1, 0)
    sm1_far = struct.pack("<HHBBBB", 0xFF00, 128, 0x02, 0, 1, 0)
    for cfg in (sm1, sm1_far):
        esc.mailbox_clear(1)
        assert seg.process(bytearray(encode_frame(Frame((Datagram.physical(Command.BWR, 0, 0, REG_SM + 8, cfg),)))))
        assert esc.mailbox_put(1, b"\x55" * 128)
        assert len(esc.mem) == end


def test_stale_syncmanager_released_on_init_request() -> None:
    """SOEM's config_init clears SM0-3 only (shared notes 'soem-interop': BWR 0x0800, 32 B), so an SM4
    left enabled over the mailbox area (by a storm) must not take the mailbox away: the ESC does not
    activate a SyncManager overlapping a lower one (issue 21; ET1100 data sheet: SyncManager buffers
    must not overlap), and on an INIT request the firmware deactivates the SMs it does not serve
    (0x0807 + 8n bit 0, PDI side), so PREOP->SAFEOP's overlap check passes again."""
    _clock, seg = fresh(1)
    esc = seg.slaves[0].esc

    def bwr(ado: int, data: bytes) -> None:
        assert seg.process(bytearray(encode_frame(Frame((Datagram.physical(Command.BWR, 0, 0, ado, data),)))))

    bwr(REG_SM + 8, struct.pack("<HHBBBB", 0x1080, 128, 0x02, 0, 1, 0))  # SM1: mailbox in
    refused = esc.stats.refused_sms
    bwr(REG_SM + 32, struct.pack("<HHBBBB", 0x1000, 0x200, 0x02, 0, 1, 0))  # SM4 over both mailboxes
    assert esc.sm_in_use(4) and not esc.sm_active(4) and esc.stats.refused_sms > refused
    assert esc.mailbox_put(1, b"reply")
    data = esc.ecat_read(0x1080, 128)  # SM1 serves the read, SM4 does not refuse it
    assert data is not None and data.startswith(b"reply")
    bwr(REG_AL_CONTROL, struct.pack("<H", AlState.INIT | 0x10))
    assert not esc.sm_in_use(4) and esc.sm_in_use(1) and esc.sm_active(1)


def _check_frame(seg: Segment, raw: bytes) -> None:
    """One storm frame: answered iff well formed; in place; WKC only grows within bounds."""
    frame = bytearray(raw)
    try:
        before = decode_frame(raw).datagrams
    except FrameFormatError:
        before = None
    sizes = [len(s.esc.mem) for s in seg.slaves]
    nobody = _addresses_nobody(seg, before[0]) if before else False
    answered = seg.process(frame)
    assert answered == (before is not None)
    assert len(frame) == len(raw)
    assert [len(s.esc.mem) for s in seg.slaves] == sizes
    if before is None:
        assert frame == raw
        return
    after = decode_frame(frame).datagrams
    if nobody:  # ETG.1000.4: a datagram no slave is addressed by passes with its working counter unchanged
        assert after[0].wkc == before[0].wkc and after[0].data == before[0].data
    for b, a in zip(before, after, strict=True):
        grown = (a.wkc - b.wkc) & 0xFFFF
        assert grown <= MAX_WKC_PER_SLAVE * len(seg.slaves)
        if b.command == Command.NOP:
            assert a == b


def _addresses_nobody(seg: Segment, d: Datagram) -> bool:
    """A configured-address datagram for a station address and alias no slave has, or an
    auto-increment one for a position past the last slave (judged before the frame runs)."""
    if d.command in (Command.FPRD, Command.FPWR, Command.FPRW, Command.FRMW):
        for s in seg.slaves:
            esc = s.esc
            alias = struct.unpack_from("<H", esc.mem, 0x0012)[0] if esc.mem[0x0103] & 1 else None
            if d.adp in (esc.station_address, alias):
                return False
        return d.command != Command.FRMW  # FRMW writes every slave that is not addressed
    if d.command in (Command.APRD, Command.APWR, Command.APRW):
        return (-d.adp) & 0xFFFF >= len(seg.slaves)
    return d.command == Command.NOP


def _recover_to_op(clock: SimulatedClock, seg: Segment) -> None:
    """The master re-initialises the line and runs process data without a wrong working counter."""
    m = Master(clock, seg)
    m.bring_up(ack_errors=True)
    for _ in range(20):
        assert m.exchange_process_data() == m.expected_wkc
    assert all(s.esc.al_state == AlState.OP for s in seg.slaves)


def test_seeded_storm_never_raises_and_master_recovers() -> None:
    """issue 15: thousands of random frames (random bytes, 1-4 datagrams of random command, address,
    length, lying lengths) processed with the clock running; afterwards a master reaches OP."""
    for seed in (1, 2):
        clock, seg = fresh()
        eeproms = [bytes(s.esc.eeprom) for s in seg.slaves]
        for i, raw in enumerate(storm(seed, 3000, keep_eeprom=True)):
            _check_frame(seg, raw)
            if i % 50 == 0:
                clock.advance(0.001)
            for s in seg.slaves:
                assert s.esc.al_status & 0x0F in VALID_STATES
        assert [bytes(s.esc.eeprom) for s in seg.slaves] == eeproms
        assert seg.stats.frames > 1000 and seg.stats.bad_frames > 100
        clock.advance(0.5)
        _recover_to_op(clock, seg)


def test_storm_that_may_write_the_eeprom_still_never_raises() -> None:
    """Without the write-enable guard a storm may reprogram the SII (as on a real ESC); processing never
    raises, and the segment still answers every well-formed frame."""
    clock, seg = fresh()
    for i, raw in enumerate(storm(7, 3000)):
        _check_frame(seg, raw)
        if i % 50 == 0:
            clock.advance(0.001)
    frame = bytearray(encode_frame(Frame((Datagram.physical(Command.BRD, 0, 0, 0x0000, b"\0\0"),))))
    assert seg.process(frame) and decode_frame(frame).datagrams[0].wkc == 3


lying_datagram = st.tuples(st.integers(0, 255), st.integers(0, 0xFFFFFFFF), st.integers(0, 0x7FF),
                           st.binary(max_size=80), st.booleans())


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(lying_datagram, min_size=1, max_size=4), st.one_of(st.none(), st.integers(0, 0x7FF)),
       st.integers(0, 15))
def test_any_datagram_header_is_processed_or_dropped(dgs: list[tuple[int, int, int, bytes, bool]],
                                                     ecat_len: int | None, ftype: int) -> None:
    """Hypothesis: any command byte, address, announced length and actual data, any EtherCAT length and
    type: the segment answers iff the codec parses the frame, raises nothing, and serves the next frame."""
    body = b"".join(struct.pack("<BBIHH", cmd, 0, addr, dlen | (0x8000 if more else 0), 0) + data + b"\0\0"
                    for cmd, addr, dlen, data, more in dgs)
    length = len(body) if ecat_len is None else ecat_len
    raw = ETH + struct.pack("<H", length | (ftype if ecat_len is not None else 1) << 12) + body
    clock, seg = fresh(2)
    _check_frame(seg, raw[:1514])
    clock.advance(0.01)
    frame = bytearray(encode_frame(Frame((Datagram.physical(Command.BRD, 0, 0, 0x0000, b"\0\0"),))))
    assert seg.process(frame) and decode_frame(frame).datagrams[0].wkc == 2
