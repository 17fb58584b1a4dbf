"""The ESC returns PDI events instead of calling the firmware (issue 22: "The ESC returns events:
process_datagram yields PDI events (SM written/read, AL control, ...) that Slave dispatches after the
datagram, so device codecs no longer run inside register access"), and ``Esc.sync0_period`` and friends
as the one way to read the DC settings ("Esc.sync0_period (and friends) instead of raw reads of ESC memory").

The event contract is in the docstring of :mod:`gatewaylab.ethercat.esc`; ET1100 data sheet section II
(AL event request 0x0220: AL control, SM change, SyncManager n; DC registers 0x0981 / 0x0990 / 0x09A0 /
0x09A4).
"""

from __future__ import annotations

import struct

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import IoApplication, io_description
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.esc import (
    REG_AL_CONTROL,
    REG_AL_STATUS,
    REG_DC_ACTIVATION,
    REG_DC_START_TIME,
    REG_DC_SYNC0_CYCLE,
    REG_DC_SYNC1_CYCLE,
    SYNC0_MIN_CYCLE_NS,
    AlControlRequested,
    AlState,
    SmRead,
    SmWritten,
)
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave
from gatewaylab.hosts.ethercat.master import Master

POS = 16  # offset of the first datagram in an encoded frame (Ethernet header + EtherCAT header)


def _frame(*datagrams: Datagram) -> bytearray:
    return bytearray(encode_frame(Frame(tuple(datagrams))))


class _CountingIo(IoApplication):
    """The loop-back box, counting its outputs callbacks (they must not run inside the ESC's access)."""

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        self.calls += 1
        super().on_outputs(slave, data)


def _io_in_op() -> tuple[Segment, Master, _CountingIo]:
    clock = SimulatedClock()
    app = _CountingIo()
    seg = Segment([Slave(clock, io_description("io", 1), app, name="io")])
    m = Master(clock, seg)
    m.bring_up()
    return seg, m, app


def test_lrw_pauses_after_the_outputs_write_so_the_same_lrw_reads_the_echo() -> None:
    """Event contract points 1, 2 and 4: the LRW's write access raises SmWritten(2) and the ESC returns
    it without calling the application, the working counter still untouched; once the event is
    delivered, resume_datagram runs the read access (SmRead(3)) and the frame carries the inputs the
    application wrote on the write event (``ethercat_io``'s loop-back); the datagram then completes
    with WKC 3 (read 1 + write 2)."""
    seg, m, app = _io_in_op()
    slave = seg.slaves[0]
    esc = slave.esc
    calls = app.calls
    s = m.slave(0)
    image = bytearray(len(m.image))
    image[s.output_offset:s.output_offset + 5] = bytes([0x5A]) + struct.pack("<hh", 1234, -2)
    frame = _frame(Datagram(Command.LRW, 1, 0, bytes(image)))

    events = esc.process_datagram(frame, POS, Command.LRW, len(image))
    assert events is not None and len(events) == 1
    written = events[0]
    assert written == SmWritten(2)
    assert esc.pdi_outputs[2][:5] == bytes(image[s.output_offset:s.output_offset + 5])
    assert app.calls == calls and decode_frame(frame).datagrams[0].wkc == 0
    slave.sm_written(2, esc.pdi_outputs[2])  # what Slave.serve_events does with SmWritten(2)
    assert app.calls == calls + 1

    events = esc.resume_datagram()
    assert events == [SmRead(3)]
    slave.sm_read(3)
    assert esc.resume_datagram() is None
    d = decode_frame(frame).datagrams[0]
    assert d.wkc == 3
    inputs = d.data[s.input_offset:s.input_offset + 5]
    assert inputs == bytes([0x5A]) + struct.pack("<hh", 1234, -2)


def test_al_control_is_served_after_the_access_before_the_next_datagram() -> None:
    """Event contract point 4: an AL control write returns AlControlRequested and AL status does not
    change inside the access; Slave.process_datagram delivers it (the AL state machine runs on the PDI
    side, as SOES's ESC_ALevent), so an AL status read later in the same frame sees the new state."""
    seg, m, _ = _io_in_op()
    slave = seg.slaves[0]
    esc = slave.esc
    station = m.slave(0).station
    raw = _frame(Datagram.physical(Command.FPWR, 1, station, REG_AL_CONTROL, struct.pack("<H", AlState.SAFEOP)))
    events = esc.process_datagram(raw, POS, Command.FPWR, 2)
    assert events == [AlControlRequested(int(AlState.SAFEOP))]
    assert esc.al_status == AlState.OP  # nothing served yet
    slave.serve_events(events)
    assert esc.al_status == AlState.SAFEOP and decode_frame(raw).datagrams[0].wkc == 1

    frame = _frame(Datagram.physical(Command.FPWR, 2, station, REG_AL_CONTROL, struct.pack("<H", AlState.PREOP)),
                   Datagram.physical(Command.FPRD, 3, station, REG_AL_STATUS, bytes(2)))
    assert seg.process(frame)
    write, read = decode_frame(frame).datagrams
    assert (write.wkc, read.wkc) == (1, 1)
    assert struct.unpack("<H", read.data)[0] == AlState.PREOP


def test_a_register_read_raises_no_event_and_completes_at_once() -> None:
    """Event contract point 2: no events, no pause -- process_datagram returns None and the datagram is
    complete (WKC written)."""
    seg, m, _ = _io_in_op()
    raw = _frame(Datagram.physical(Command.FPRD, 1, m.slave(0).station, REG_AL_STATUS, bytes(2)))
    assert seg.slaves[0].esc.process_datagram(raw, POS, Command.FPRD, 2) is None
    assert decode_frame(raw).datagrams[0].wkc == 1


def test_sync0_settings_come_from_the_dc_unit() -> None:
    """ET1100 II DC registers: SYNC0 runs when 0x0981 has the cyclic unit and SYNC0 bits (0x03); its
    period is 0x09A0 (raised to SYNC0_MIN_CYCLE_NS, docs/decisions.md), 0 while off; the start time is
    0x0990 and SYNC1's cycle 0x09A4, read back as the master wrote them."""
    seg, m, _ = _io_in_op()
    esc = seg.slaves[0].esc
    station = m.slave(0).station
    assert not esc.sync0_active and esc.sync0_period == 0.0
    m.fpwr(station, REG_DC_SYNC0_CYCLE, struct.pack("<I", 2_000_000))
    m.fpwr(station, REG_DC_SYNC1_CYCLE, struct.pack("<I", 500_000))
    m.fpwr(station, REG_DC_START_TIME, struct.pack("<Q", 123_456_789))
    assert esc.sync0_cycle_ns == 2_000_000 and esc.sync0_period == 0.0  # programmed, not activated
    m.fpwr(station, REG_DC_ACTIVATION, b"\x03")
    assert esc.sync0_active and not esc.sync1_active
    assert esc.sync0_period == 0.002 and esc.sync1_cycle_ns == 500_000
    assert esc.sync0_start_time_ns == 123_456_789
    m.fpwr(station, REG_DC_SYNC0_CYCLE, struct.pack("<I", 1))
    assert esc.sync0_cycle_ns == 1 and esc.sync0_period == SYNC0_MIN_CYCLE_NS / 1e9
    m.fpwr(station, REG_DC_ACTIVATION, b"\x07")
    assert esc.sync1_active
    m.fpwr(station, REG_DC_ACTIVATION, b"\x01")
    assert not esc.sync0_active and esc.sync0_period == 0.0
