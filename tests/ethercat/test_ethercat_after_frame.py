"""Outputs delivered after the frame (issue 23, the 1 kHz segment): an application with
``outputs_in_frame = False`` (the ``ethercat_drive``) gets its SM2 buffer from ``Segment.after_frame``,
once the frame is on its way back, as a real ESC answers a frame as it passes while the firmware reads
the SM2 buffer after its interrupt (ET1100 data sheet section I, "SyncManager": the buffer-written event
raises the PDI interrupt; the firmware reads the buffer then). ``ethercat_io`` keeps its loop-back inside
the same LRW (the event contract in :mod:`gatewaylab.ethercat.esc`, point 4).
"""

from __future__ import annotations

import struct

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_drive import EthercatDrive
from gatewaylab.devices.ethercat_io.device import IoApplication, io_description
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave
from gatewaylab.hosts.ethercat.master import Master

RX = struct.Struct("<HiihB")   # the drive's default RxPDO 0x1600


class _Line:
    """A drive and an io box; the master's link processes each frame with ``defer`` as set."""

    def __init__(self, io_app: IoApplication | None = None) -> None:
        self.clock = SimulatedClock()
        self.drive = EthercatDrive(self.clock, "drive", serial=1)
        self.io = Slave(self.clock, io_description("io", 2), io_app or IoApplication(), name="io")
        self.segment = Segment([self.drive.slave, self.io])
        self.defer = False
        self.master = Master(self.clock, link=self._link)
        m = self.master
        m.scan()
        m.set_state(AlState.PREOP)
        m.config_map()
        m.set_state(AlState.SAFEOP)
        self.cycle(2)
        m.set_state(AlState.OP)
        self.cycle(2)

    def _link(self, raw: bytes) -> bytes | None:
        buf = bytearray(raw)
        return bytes(buf) if self.segment.process(buf, defer=self.defer) else None

    def cycle(self, n: int = 1) -> None:
        for _ in range(n):
            self.master.exchange_process_data()
            self.segment.after_frame()
            self.clock.advance(0.001)


def test_drive_outputs_wait_for_after_frame_while_the_io_echo_is_in_the_same_lrw() -> None:
    """With ``defer=True`` (the wire thread): the LRW's outputs reach the io box inside the frame (its
    inputs in the same LRW echo them) but not the drive, whose controlword object keeps its value until
    ``Segment.after_frame``; then it is stored and the drive applied it (CiA 402 'shutdown' 0x06:
    ready to switch on in the next frame's statusword)."""
    line = _Line()
    line.defer = True
    m = line.master
    m.pdo_write(0, 0, RX.pack(0x06, 0, 0, 0, 8))
    m.pdo_write(1, 0, bytes([0x5A, 0x34, 0x12, 0x00, 0x00]))
    m.exchange_process_data()
    assert m.pdo_read(1, 0, 3) == bytes([0x5A, 0x34, 0x12])      # the echo of this very LRW
    slave = line.drive.slave
    assert slave.outputs_pending and line.drive.slave.od.values[(0x6040, 0)] == 0
    line.segment.after_frame()
    assert not slave.outputs_pending and slave.od.values[(0x6040, 0)] == 0x06
    line.clock.advance(0.001)
    m.exchange_process_data()
    assert struct.unpack_from("<H", m.pdo_read(0, 0, 2))[0] & 0x6F == 0x21   # ready to switch on


def test_process_without_defer_leaves_no_work_behind() -> None:
    """``Segment.process`` without ``defer`` (the in-process master, tests) runs the applications' work
    before it returns: the drive holds the controlword of the frame just processed."""
    line = _Line()
    line.master.pdo_write(0, 0, RX.pack(0x06, 0, 0, 0, 8))
    line.master.exchange_process_data()
    assert not line.drive.slave.outputs_pending
    assert line.drive.slave.od.values[(0x6040, 0)] == 0x06


def test_work_a_caller_left_runs_before_the_next_frame_processed_without_defer() -> None:
    """A caller that deferred and never called ``after_frame``, then a frame without ``defer`` (the in-process
    master): it leaves no work behind, the pending outputs' included."""
    line = _Line()
    line.defer = True
    m = line.master
    m.pdo_write(0, 0, RX.pack(0x06, 0, 0, 0, 8))
    m.exchange_process_data()
    line.defer = False
    m.pdo_write(0, 0, RX.pack(0x07, 0, 0, 0, 8))
    cycles = line.drive.slave.cycles
    m.exchange_process_data()      # delivers 0x06 first, then 0x07 at its end
    assert line.drive.slave.cycles == cycles + 1
    assert not line.drive.slave.outputs_pending
    assert line.drive.slave.od.values[(0x6040, 0)] == 0x07


def test_deferring_caller_gets_the_newest_outputs_when_it_runs_the_work() -> None:
    """With ``defer`` (the wire thread, which answers every waiting frame first -- the second frame of a split
    process image must not wait for the first one's applications): frames do not run the work left pending;
    ``after_frame`` then hands each application the newest outputs of its SyncManager, as a slave's firmware
    reads the 3-buffer SM's latest buffer whenever it gets to it (ETG.1000.4 / ET1100 data sheet,
    'SyncManager: buffered mode': the ECAT side may write several times before the PDI reads)."""
    line = _Line()
    line.defer = True
    m = line.master
    m.pdo_write(0, 0, RX.pack(0x06, 0, 0, 0, 8))
    m.exchange_process_data()
    m.pdo_write(0, 0, RX.pack(0x07, 0, 0, 0, 8))
    before = line.drive.slave.od.values[(0x6040, 0)]
    m.exchange_process_data()
    assert line.drive.slave.outputs_pending and line.drive.slave.od.values[(0x6040, 0)] == before
    line.segment.after_frame()
    assert not line.drive.slave.outputs_pending
    assert line.drive.slave.od.values[(0x6040, 0)] == 0x07


class _LateFaulty(IoApplication):
    """An io box taking its outputs after the frame, whose outputs handler raises (a defect)."""

    outputs_in_frame = False

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        raise RuntimeError("defect in the device's application")


def test_an_application_raising_after_the_frame_costs_only_its_own_delivery(
        caplog: pytest.LogCaptureFixture) -> None:
    """DEVELOPERS.md principle 4 ('never a crash'): the io's handler raises in ``after_frame``; the error is
    counted and logged as a datagram error of that slave, the drive still gets its outputs, the frames
    keep their working counters."""
    line = _Line(_LateFaulty())
    line.defer = True
    errors = line.segment.stats.datagram_errors
    m = line.master
    m.pdo_write(0, 0, RX.pack(0x06, 0, 0, 0, 8))
    assert m.exchange_process_data() == m.expected_wkc
    line.segment.after_frame()
    assert line.segment.stats.datagram_errors == errors + 1
    assert "defect in the device's application" in line.segment.stats.errors[-1]
    assert line.drive.slave.od.values[(0x6040, 0)] == 0x06


class _ReadCounter(IoApplication):
    """An io box that hears of the master's inputs read after the frame (the ECAN-Lite's choice), counting
    the reads and the frame the counter was in when it heard of one."""

    inputs_read_in_frame = False

    def __init__(self) -> None:
        super().__init__()
        self.reads = 0

    def on_inputs_read(self, slave: Slave) -> None:
        self.reads += 1
        super().on_inputs_read(slave)


def test_inputs_read_reaches_an_application_after_the_frame_when_it_asks() -> None:
    """ET1100 data sheet section I, "SyncManager": the buffer-read event of the inputs SM (3-buffer mode) raises
    the PDI interrupt and the firmware serves it between frames. With ``inputs_read_in_frame = False`` and
    ``defer`` (the wire thread) the read is pending after the LRW and told by ``after_frame``, once per
    ``after_frame`` however many reads came (the firmware sees the interrupt, not a count); without ``defer``
    it is told before ``process`` returns."""
    app = _ReadCounter()
    line = _Line(app)
    line.defer = True
    slave = line.io
    reads = app.reads
    line.master.exchange_process_data()
    assert slave.inputs_read_pending and app.reads == reads
    line.master.exchange_process_data()
    line.segment.after_frame()
    assert not slave.inputs_read_pending and app.reads == reads + 1
    line.defer = False
    line.master.exchange_process_data()
    assert not slave.inputs_read_pending and app.reads == reads + 2


def test_a_pending_inputs_read_is_forgotten_when_the_slave_leaves_safeop_and_op() -> None:
    """ETG.1000.6 (AL state machine): the process data exchange stops below SAFEOP, so a read left pending when
    the master takes the slave to PREOP is not told to the application afterwards."""
    app = _ReadCounter()
    line = _Line(app)
    line.defer = True
    line.master.exchange_process_data()
    assert line.io.inputs_read_pending
    reads = app.reads
    line.master.set_state(AlState.PREOP)      # still deferring: nothing ran the pending work
    assert not line.io.inputs_read_pending
    line.segment.after_frame()
    assert app.reads == reads
