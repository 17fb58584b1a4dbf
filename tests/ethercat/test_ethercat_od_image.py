"""The process image is backed by the object dictionary (issue 9 'Object hooks for devices'):
a CoE read of a mapped object returns what the process data carries, as SOES binds object rows
to process variables (ETG.1000.6 CoE: an SDO upload of a mapped object reads its present value)."""

from __future__ import annotations

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import Entry, ObjectDictionary


def _op(master: Master) -> None:
    master.set_state(AlState.PREOP)
    master.config_map()
    master.set_state(AlState.SAFEOP)
    master.set_state(AlState.OP)


def test_coe_read_of_mapped_input_returns_the_live_value(master: Master, segment: Segment) -> None:
    """ETG.1000.6 CoE SDO upload of 0x6010:01 / 0x6020:01 (TxPDO-mapped inputs) in OP: the same
    value the master reads from the process image in that cycle, not the power-on default."""
    _op(master)
    for i in range(5):
        master.pdo_write16(0, 1, 1000 + i)
        master.exchange_process_data()
    assert master.pdo_read16(0, 1) == 1004
    assert master.sdo_upload16(0, 0x6010, 1) == 1004
    assert master.sdo_upload32(0, 0x6020, 1) == master.pdo_read32(0, 5) == 5
    assert master.sdo_upload16(0, 0x7010, 1) == 1004          # the mapped output as received


def test_raw_inputs_are_decoded_for_coe_reads(master: Master, segment: Segment) -> None:
    """A device that writes its inputs as raw bytes (``write_inputs``) still answers CoE reads of
    the mapped objects from the image (ETG.1000.6: one value per object)."""
    _op(master)
    slave = segment.slaves[1]
    slave.write_inputs(bytes([0xA5]))
    assert master.sdo_upload8(1, 0x6000, 1) == 0xA5
    slave.write_input(0x6010, 2, -7)
    assert slave.inputs[3:5] == (-7).to_bytes(2, "little", signed=True)
    assert master.sdo_upload16(1, 0x6010, 2) == (-7) & 0xFFFF


def test_application_binds_read_hooks_and_apply_commands() -> None:
    """Issue 9: a device answers status objects and 'apply' commands from its model through hooks
    set up in ``SlaveApplication.setup_od`` (CiA 301 / ETG.1000.6 SDO upload/download)."""
    from gatewaylab.devices.ethercat_io.device import io_description

    applied: list[int] = []

    class App(SlaveApplication):
        reads = 0

        def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
            def refresh(index: int, subindex: int) -> None:
                App.reads += 1
                od.put(0x8000, 2, 40 + App.reads)

            def apply(entry: Entry, value: object) -> None:
                applied.append(int(str(value)))

            od.on_read(range(0x8000, 0x8001), refresh)
            od.add_reaction(0x8001, apply)

    clock = SimulatedClock()
    m = Master(clock, Segment([Slave(clock, io_description(), App())]))
    m.scan()
    m.set_state(AlState.PREOP)
    assert m.sdo_upload32(0, 0x8000, 2) == 41
    assert m.sdo_upload32(0, 0x8000, 2) == 42
    m.sdo_download16(0, 0x8001, 0, 0x1234)
    assert applied == [0x1234]
