"""``ethercat_io``: a small generic digital/analog I/O slave for the core's tests and examples.

Outputs (RxPDO 0x1600): 0x7000:01 digital outputs (U8), 0x7010:01/02 analog outputs (INT16).
Inputs (TxPDO 0x1A00): 0x6000:01 digital inputs, 0x6010:01/02 analog inputs, 0x6020:01 cycle counter.
Settings: 0x8000:01 description string (RW), 0x8000:02 scale (RW), 0x8001 emergency trigger (RW).
The inputs echo the outputs (a wired loop-back test box): the application runs on the SM2 write
event, before the same LRW reads SM3, so one LRW returns its own outputs. The counter counts output
cycles, so a master can check both directions of process data.
"""

from __future__ import annotations

import struct

from ..common.clock import Clock
from .description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from .esc import AlState
from .foe import FoeHandler
from .od import Access, DataType, Entry
from .slave import Slave, SlaveApplication

VENDOR_ID = 0x47574C42  # 'GWLB', not an ETG-assigned id (see docs/decisions.md)
PRODUCT_CODE = 0x00010001
_IN = struct.Struct("<BhhI")
_OUT = struct.Struct("<Bhh")


def io_description(name: str = "GL-IO 8DIO 2AIO", serial: int = 0, revision: int = 1) -> DeviceDescription:
    rx = Pdo(0x1600, "Outputs", (
        PdoEntry(0x7000, 1, 8, "Digital outputs", DataType.UNSIGNED8),
        PdoEntry(0x7010, 1, 16, "Analog output 1", DataType.INTEGER16),
        PdoEntry(0x7010, 2, 16, "Analog output 2", DataType.INTEGER16),
    ))
    tx = Pdo(0x1A00, "Inputs", (
        PdoEntry(0x6000, 1, 8, "Digital inputs", DataType.UNSIGNED8),
        PdoEntry(0x6010, 1, 16, "Analog input 1", DataType.INTEGER16),
        PdoEntry(0x6010, 2, 16, "Analog input 2", DataType.INTEGER16),
        PdoEntry(0x6020, 1, 32, "Cycle counter", DataType.UNSIGNED32),
    ))
    rw_out = Access.RW | Access.RXPDO
    ro_in = Access.RO | Access.TXPDO
    return DeviceDescription(
        name=name, vendor_id=VENDOR_ID, product_code=PRODUCT_CODE, revision=revision, serial=serial,
        order_code="GL-IO-8D2A", rx_pdos=(rx,), tx_pdos=(tx,), device_type=0x00001389,
        objects=(
            ObjectDef(0x6000, "Digital inputs", subs=(("Digital inputs", DataType.UNSIGNED8, 0, ro_in),)),
            ObjectDef(0x6010, "Analog inputs", subs=(("Analog input 1", DataType.INTEGER16, 0, ro_in),
                                                     ("Analog input 2", DataType.INTEGER16, 0, ro_in))),
            ObjectDef(0x6020, "Counters", subs=(("Cycle counter", DataType.UNSIGNED32, 0, ro_in),)),
            ObjectDef(0x7000, "Digital outputs", subs=(("Digital outputs", DataType.UNSIGNED8, 0, rw_out),)),
            ObjectDef(0x7010, "Analog outputs", subs=(("Analog output 1", DataType.INTEGER16, 0, rw_out),
                                                      ("Analog output 2", DataType.INTEGER16, 0, rw_out))),
            ObjectDef(0x8001, "Emergency trigger", DataType.UNSIGNED16, 0, Access.RW),
            ObjectDef(0x8000, "Settings", subs=(("Description", DataType.VISIBLE_STRING,
                                                 "generic loop-back I/O test box", Access.RW),
                                                ("Scale", DataType.UNSIGNED32, 1, Access.RW))),
        ))


class IoApplication(SlaveApplication):
    """Loop-back behaviour: inputs = previous outputs, counter = number of output cycles."""

    def __init__(self) -> None:
        self.counter = 0
        self.sync0_count = 0

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        self.counter = (self.counter + 1) & 0xFFFFFFFF
        if len(data) >= _OUT.size and slave.input_bytes >= _IN.size:
            digital, a1, a2 = _OUT.unpack_from(data, 0)
            slave.write_inputs(_IN.pack(digital, a1, a2, self.counter))

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        if new == AlState.SAFEOP and old == AlState.PREOP:
            self.counter = 0

    def on_sync0(self, slave: Slave, t: float) -> None:
        self.sync0_count += 1


def create_io_slave(clock: Clock, name: str = "GL-IO 8DIO 2AIO", serial: int = 0,
                    foe: FoeHandler | None = None, revision: int = 1) -> Slave:
    """An ``ethercat_io`` slave ready to be put in a segment.

    Writing an error code to 0x8001 makes the box send that CoE emergency right after the SDO
    response (fault injection for masters' emergency handling)."""
    slave = Slave(clock, io_description(name, serial, revision), IoApplication(), foe, name=name)

    def trigger(entry: Entry, data: bytes) -> None:
        code = int.from_bytes(data[:2], "little")
        if code:
            clock.call_soon(slave.emergency, code, 0x01, b"GL-IO")

    slave.od.entry(0x8001, 0).on_write = trigger
    return slave
