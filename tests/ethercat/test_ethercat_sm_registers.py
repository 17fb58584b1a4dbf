"""SyncManagers over the ESC registers, and datagrams that raise (issue 21, defect 2: "A mailbox reply can
overwrite ESC registers and the segment never recovers").

ET1100 data sheet section II: the registers are 0x0000-0x0FFF and the process RAM starts at 0x1000; AL
status 0x0130 and AL status code 0x0134 are read-only for the master (ECAT r/-). SOES ``ESC_sm_act_event``:
on a SyncManager change in PREOP and above, mailbox SyncManagers that no longer match the SII stop the
mailbox with INIT + error and AL status code 0x0016 "invalid mailbox configuration"; process data
SyncManagers that no longer fit drop SAFEOP/OP to PREOP + error with 0x001D / 0x001E (ETG.1000.6 AL
status codes).
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from ethercat_rig_kit import KINDS, kind_rig, reinitialise
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.devices.ethercat_io.device import IoApplication, io_description
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.errors import AlStatusCode, MasterError
from gatewaylab.ethercat.esc import (
    AL_ERROR,
    REG_AL_CONTROL,
    REG_AL_STATUS,
    REG_SM,
    SM_REG,
    AlState,
)
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave
from gatewaylab.hosts.ethercat.master import Master

BROKEN = 1  # the esd gateway: the slave whose SM1 the test moves


def _frame(*datagrams: Datagram) -> bytearray:
    return bytearray(encode_frame(Frame(tuple(datagrams))))


def test_sm1_over_al_status_then_sdo_upload_leaves_registers_and_line_intact(tmp_path: Path) -> None:
    """The issue's reproduction: a line of all four kinds in OP; the master moves SM1 of one slave to 0x0130
    (disable, then program start 0x0130) and sends one SDO upload. The ESC does not activate a
    SyncManager over the registers, so the reply never reaches AL status; the firmware refuses the
    mailbox configuration (INIT + error, 0x0016). The next frame, holding an AL control write for every
    slave and reads of each slave's AL status, is processed for every slave, the other three stay in
    OP, and the master's normal re-initialisation brings all four back to OP."""
    rig, clock, seg = kind_rig(tmp_path, KINDS)
    try:
        m = Master(clock, seg)
        m.bring_up()
        m.start_cyclic(0.001)  # process data keeps running (the SM watchdogs of the others stay fed)
        s = m.slave(BROKEN)
        esc = seg.slaves[BROKEN].esc
        m.fpwr(s.station, REG_SM + 8 + 6, b"\0")  # SM1 activate = 0
        m.fpwr(s.station, REG_SM + 8, SM_REG.pack(0x0130, s.mailbox_in[1], 0x22, 0, 1, 0))
        with pytest.raises((TimeoutError_, MasterError)):
            m.sdo_upload(BROKEN, 0x1018, 1)  # no reply can be placed: the mailbox is stopped
        m.stop_cyclic()
        assert esc.al_status == AlState.INIT | AL_ERROR
        assert esc.al_status_code == AlStatusCode.INVALID_MAILBOX_CONFIG
        assert bytes(esc.mem[REG_AL_STATUS + 2:REG_AL_STATUS + 4]) == b"\0\0"  # reserved bytes untouched
        assert not esc.sm_active(1) and esc.stats.refused_sms > 0
        frame = _frame(Datagram.physical(Command.BWR, 0, 0, REG_AL_CONTROL, struct.pack("<H", AlState.OP)),
                       *(Datagram.physical(Command.FPRD, 0, x.station, REG_AL_STATUS, bytes(2)) for x in m.slaves))
        assert seg.process(frame)
        back = decode_frame(frame).datagrams
        assert back[0].wkc == len(KINDS)  # every slave took the AL control write
        states = [struct.unpack("<H", d.data)[0] for d in back[1:]]
        assert [d.wkc for d in back[1:]] == [1] * len(KINDS)
        assert states == [AlState.OP if i != BROKEN else AlState.INIT | AL_ERROR for i in range(len(KINDS))]
        assert seg.stats.datagram_errors == 0
        reinitialise(clock, seg)
        assert [x.state for x in seg.slaves] == [AlState.OP] * len(KINDS)
        assert esc.sm_active(1) and esc.al_status_code == 0
    finally:
        rig.close()


def _io_line(n: int = 2) -> tuple[SimulatedClock, Segment, Master]:
    clock = SimulatedClock()
    seg = Segment([Slave(clock, io_description(f"io{i}", i, i + 1), IoApplication(), name=f"io{i}")
                   for i in range(n)])
    m = Master(clock, seg)
    m.bring_up()
    return clock, seg, m


@pytest.mark.parametrize("start", [0x0130, 0x0000, 0x0800, 0x0FF8, 0x1000])
def test_mailbox_sm_over_registers_or_another_sm_is_not_activated(start: int) -> None:
    """SM1 programmed in one write (no disable first) over the registers, or over SM0: the ESC does not
    activate it (buffers only in process RAM, never overlapping a lower SyncManager), the firmware reports
    0x0016 in INIT + error, the reply a request would produce is never stored (``mailbox_put`` refuses),
    and AL status keeps a defined state."""
    _clock, seg, m = _io_line()
    s, esc = m.slave(0), seg.slaves[0].esc
    m.fpwr(s.station, REG_SM + 8, SM_REG.pack(start, 128, 0x22, 0, 1, 0))
    assert not esc.mailbox_put(1, b"\x0a" * 128)
    assert (esc.al_status, esc.al_status_code) == (AlState.INIT | AL_ERROR, AlStatusCode.INVALID_MAILBOX_CONFIG)
    assert esc.sm_in_use(1) and not esc.sm_active(1)
    assert seg.slaves[1].state == AlState.OP


@pytest.mark.parametrize(("sm", "code"), [(2, AlStatusCode.INVALID_OUTPUT_CONFIG),
                                          (3, AlStatusCode.INVALID_INPUT_CONFIG)])
def test_process_data_sm_over_registers_in_op_drops_to_preop(sm: int, code: int) -> None:
    """SM2 (outputs) or SM3 (inputs) moved over the registers while in OP: not activated by the ESC, and the
    firmware drops to PREOP + error with 0x001D / 0x001E; the mailbox keeps working (an SDO upload
    answers) and the master's re-initialisation reaches OP again."""
    clock, seg, m = _io_line()
    s, slave = m.slave(0), seg.slaves[0]
    cfg = slave.esc.sm_config(sm)
    m.fpwr(s.station, REG_SM + 8 * sm, SM_REG.pack(0x0130, cfg.length, cfg.control, 0, 1, 0))
    assert (slave.esc.al_status, slave.esc.al_status_code) == (AlState.PREOP | AL_ERROR, code)
    assert not slave.esc.sm_active(sm)
    assert m.sdo_upload32(0, 0x1018, 1) == slave.desc.vendor_id
    reinitialise(clock, seg)
    assert [x.state for x in seg.slaves] == [AlState.OP, AlState.OP]


def test_pdi_writes_reach_process_ram_only() -> None:
    """Registers and process RAM are separate (ET1100 data sheet II): the application's writes into DPRAM
    (``pdi_write``) never land below 0x1000, so AL status keeps its value."""
    _clock, seg, _m = _io_line(1)
    esc = seg.slaves[0].esc
    before = bytes(esc.mem[:0x1000])
    esc.pdi_write(0x0130, b"\x0a" * 0x20)
    esc.pdi_write(0x0FF0, b"\x55" * 0x20)
    assert bytes(esc.mem[:0x1000]) == before
    assert bytes(esc.mem[0x1000:0x1010]) == b"\x55" * 0x10


class _Faulty(IoApplication):
    """An application with a defect: its outputs handler raises."""

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        raise RuntimeError("defect in the device's application")


def test_a_datagram_that_raises_costs_neither_the_frame_nor_the_other_slaves() -> None:
    """DEVELOPERS.md principle 4 ("never a crash"), issue 21 ("no exception from one datagram ever drops the
    other datagrams of the frame"): slave 0's application raises on its outputs. The frame still comes back;
    slave 1 processes the same LRW (its working counter share) and the frame's other datagrams; the error
    is counted on the segment and on that ESC; the next frame is served as usual."""
    clock = SimulatedClock()
    seg = Segment([Slave(clock, io_description("bad", 1, 1), _Faulty(), name="bad"),
                   Slave(clock, io_description("good", 2, 2), IoApplication(), name="good")])
    m = Master(clock, seg)
    m.bring_up()  # the faulty outputs handler runs from SAFEOP->OP's first cycle on
    a, b = m.slaves
    frame = _frame(Datagram(Command.LRW, 1, 0, bytes(len(m.image))),
                   Datagram.physical(Command.FPRD, 2, a.station, REG_AL_STATUS, bytes(2)),
                   Datagram.physical(Command.FPRD, 3, b.station, REG_AL_STATUS, bytes(2)))
    assert seg.process(frame)
    lrw, st_a, st_b = decode_frame(frame).datagrams
    assert lrw.wkc == 3  # slave 1: read + write; slave 0's datagram raised before it counted
    assert (st_a.wkc, st_b.wkc) == (1, 1)
    assert seg.stats.datagram_errors == 1 and seg.slaves[0].esc.stats.datagram_errors > 0
    assert "RuntimeError" in seg.stats.errors[-1]
    assert m.exchange_process_data() == 3


# ------------------------------------------------------------------ hypothesis: any datagram, any slave
#: Registers the master must never change and the ESC never changes by itself (ET1100 II, ECAT r/-):
#: information, PDI control and configuration, AL event mask / request, EEPROM PDI access state.
STATIC_RO = ((0x0000, 0x0010), (0x0140, 0x0142), (0x0150, 0x0154), (0x0204, 0x0208), (0x0220, 0x0228),
             (0x0501, 0x0502))
VALID_STATES = {int(s) for s in AlState}
VALID_CODES = {int(c) for c in AlStatusCode}
SM_OVER_REGISTERS = st.builds(
    lambda n, start, length, ctrl: (Command.FPWR, REG_SM + 8 * n, SM_REG.pack(start, length, ctrl, 0, 1, 0)),
    st.sampled_from([1, 1, 1, 0, 2, 3, 4, 5]),
    st.one_of(st.sampled_from([0x0130, 0x0120, 0x0000, 0x0800, 0x1000, 0x1080]), st.integers(0, 0x1FFF)),
    st.sampled_from([2, 6, 128, 256]), st.sampled_from([0x22, 0x26, 0x24, 0x20, 0x64]))
SDO_REQUEST = st.just((Command.FPWR, 0x1000, struct.pack("<HHBB", 10, 0, 0, 0x03)  # counter 0: always served
                       + struct.pack("<HBHB4x", 0x2000, 0x40, 0x1018, 1) + bytes(112)))
ANY = st.tuples(st.integers(0, 255).map(lambda c: Command(c) if c <= 14 else c),
                st.one_of(st.integers(0, 0x1100), st.integers(0, 0xFFFF)), st.binary(max_size=300))
READ_MBX = st.just((Command.FPRD, 0x1080, bytes(128)))
AL_REQUEST = st.builds(lambda v: (Command.FPWR, REG_AL_CONTROL, struct.pack("<H", v)), st.integers(0, 0x1F))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(SM_OVER_REGISTERS, SDO_REQUEST, ANY, READ_MBX, AL_REQUEST), min_size=1, max_size=12))
def test_any_datagram_never_raises_nor_writes_read_only_registers(
        steps: list[tuple[int, int, bytes]]) -> None:
    """Hypothesis over sequences of datagrams for one slave in OP: any command byte (0-255), address
    (register area included), length and data, SyncManagers programmed over the registers, SDO requests
    into SM0, mailbox reads and AL control values 0x00-0x1F. ``Slave.process_datagram`` (the ESC and the
    delivery of its PDI events to the firmware) never raises; the static read-only registers keep their
    values; AL status always holds a defined state (bits 0-4: state + error flag, ETG.1000.6) and AL
    status code a code of the ETG.1000.6 table."""
    clock, seg, m = _io_line(1)
    esc = seg.slaves[0].esc
    station = m.slave(0).station
    static = [bytes(esc.mem[lo:hi]) for lo, hi in STATIC_RO]
    for cmd, ado, data in steps:
        raw = _frame(Datagram.physical(Command.NOP, 0, station, ado, data))
        seg.slaves[0].process_datagram(raw, 16, int(cmd) & 0xFF, len(data))  # any command byte, unknown ones too
        clock.advance(0.001)
        assert [bytes(esc.mem[lo:hi]) for lo, hi in STATIC_RO] == static
        status = esc.al_status
        assert status & 0x0F in VALID_STATES and not status & ~0x1F, hex(status)
        assert esc.al_status_code in VALID_CODES, hex(esc.al_status_code)
