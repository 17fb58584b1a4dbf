"""``ethercat_io``: a small generic digital/analog I/O slave for the core's tests and examples.

Outputs (RxPDO 0x1600): 0x7000:01 digital outputs (U8), 0x7010:01/02 analog outputs (INT16).
Inputs (TxPDO 0x1A00): 0x6000:01 digital inputs, 0x6010:01/02 analog inputs, 0x6020:01 cycle counter.
Settings: 0x8000:01 description string (RW, at most 512 bytes: STRING(512)), 0x8000:02 scale (RW),
0x8001 emergency trigger (RW).
The inputs echo the outputs (a wired loop-back test box): the application runs on the SM2 write
event, before the same LRW reads SM3, so one LRW returns its own outputs. The counter counts output
cycles, so a master can check both directions of process data.
"""

from __future__ import annotations

import struct
from dataclasses import replace
from typing import Any, Final

from mypy_extensions import mypyc_attr

from gatewaylab.common.clock import Clock
from gatewaylab.ethercat.description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.foe import FoeHandler
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.od import Access, DataType, Entry, ObjectDictionary, key_object

VENDOR_ID = 0x47574C42  # 'GWLB', not an ETG-assigned id (see docs/decisions.md)
PRODUCT_CODE = 0x00010001
#: The default outputs image (RxPDO 0x1600): digital outputs, analog outputs 1 and 2.
_OUTPUTS: Final = struct.Struct("<Bhh")
_DEFAULT_OUTPUTS: Final = ((0x7000, 1, 0, 8), (0x7010, 1, 8, 16), (0x7010, 2, 24, 16))
#: Loop-back wiring: output object -> input object that echoes it.
_ECHO: Final = (((0x7000, 1), (0x6000, 1)), ((0x7010, 1), (0x6010, 1)), ((0x7010, 2), (0x6010, 2)))
#: The inputs the default echo writes each cycle, in order: the echoed outputs, then the counter.
_COUNTER: Final = (0x6020, 1)
_ECHO_INPUTS: Final = tuple(key_object(*k) for k in (*(inp for _, inp in _ECHO), _COUNTER))
#: Bytes the description string 0x8000:01 holds (its ESI STRING(n)): longer than a mailbox, so it
#: carries segmented transfers; a longer write aborts 0x06070012.
DESCRIPTION_LENGTH: Final = 512


def _declare_sizes(od: ObjectDictionary) -> None:
    """The description string's buffer (its default is shorter than what it holds)."""
    od.replace_entry(replace(od.entry(0x8000, 1), max_length=DESCRIPTION_LENGTH))


def io_description(name: str = "GL-IO 8DIO 2AIO", serial: int = 0, revision: int = 1) -> DeviceDescription:
    """The ``ethercat_io`` box: identity, one RxPDO and one TxPDO, the objects behind them."""
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
    rw_out = Access.RWW   # mappable into the RxPDO only
    ro_in = Access.RO     # mappable into the TxPDO
    return DeviceDescription(
        name=name, vendor_id=VENDOR_ID, product_code=PRODUCT_CODE, revision=revision, serial=serial,
        order_code="GL-IO-8D2A", rx_pdos=(rx,), tx_pdos=(tx,), device_type=0x00001389, extend_od=_declare_sizes,
        objects=(
            ObjectDef(0x6000, "Digital inputs", subs=(("Digital inputs", DataType.UNSIGNED8, 0, ro_in),),
                      pdo_mappable=True),
            ObjectDef(0x6010, "Analog inputs", subs=(("Analog input 1", DataType.INTEGER16, 0, ro_in),
                                                     ("Analog input 2", DataType.INTEGER16, 0, ro_in)),
                      pdo_mappable=True),
            ObjectDef(0x6020, "Counters", subs=(("Cycle counter", DataType.UNSIGNED32, 0, ro_in),),
                      pdo_mappable=True),
            ObjectDef(0x7000, "Digital outputs", subs=(("Digital outputs", DataType.UNSIGNED8, 0, rw_out),),
                      pdo_mappable=True),
            ObjectDef(0x7010, "Analog outputs", subs=(("Analog output 1", DataType.INTEGER16, 0, rw_out),
                                                      ("Analog output 2", DataType.INTEGER16, 0, rw_out)),
                      pdo_mappable=True),
            ObjectDef(0x8001, "Emergency trigger", DataType.UNSIGNED16, 0, Access.RW),
            ObjectDef(0x8000, "Settings", subs=(("Description", DataType.VISIBLE_STRING,
                                                 "generic loop-back I/O test box", Access.RW),
                                                ("Scale", DataType.UNSIGNED32, 1, Access.RW))),
        ))


@mypyc_attr(allow_interpreted_subclasses=True)  # tests subclass it (counting, faulty boxes)
class IoApplication(SlaveApplication):
    """Loop-back behaviour: inputs = previous outputs, counter = number of output cycles; writing an
    error code to 0x8001 sends that CoE emergency right after the SDO response."""

    #: The echo reads the outputs image itself (one struct for the default mapping): storing them into
    #: 0x7000/0x7010 every cycle first would cost three more dictionary writes inside the frame; a CoE
    #: read of 0x7000/0x7010 decodes them from the image (Slave's read hook).
    store_outputs = False

    def __init__(self) -> None:
        self.counter = 0
        self.sync0_count = 0
        #: the outputs are mapped as the description maps them (set at PREOP -> SAFEOP)
        self._default_outputs = True

    def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
        """0x8001 'Emergency trigger' is an apply command: a reaction sends the emergency."""

        def trigger(entry: Entry, value: Any) -> None:
            if value:
                slave.clock.call_soon(slave.emergency, int(value), 0x01, b"GL-IO")

        od.add_reaction(0x8001, trigger)

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        """Echo the outputs 0x7000/0x7010 (as the master sent them) into the input objects."""
        self.counter = (self.counter + 1) & 0xFFFFFFFF
        od = slave.od
        if self._default_outputs and len(data) >= _OUTPUTS.size:
            # one dictionary call with the interned keys; "<Bhh" yields ints that fit U8 / INT16 and the
            # counter is masked to U32: typed, stored without coercion (this runs inside the frame)
            digital, analog1, analog2 = _OUTPUTS.unpack_from(data, 0)
            od.put_many(_ECHO_INPUTS, (digital, analog1, analog2, self.counter), typed=True)
            return
        for out_key, in_key in _ECHO:
            try:
                value = slave.read_output(out_key[0], out_key[1])
            except EtherCATConfigError:     # not mapped: the object's own value
                value = od.values[out_key]
            od.put(in_key[0], in_key[1], value)
        od.put(*_COUNTER, self.counter)

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        """The counter restarts with every PREOP -> SAFEOP (the output mapping is known then)."""
        if new == AlState.SAFEOP and old == AlState.PREOP:
            self.counter = 0
            layout = [(m.index, m.subindex, m.bit_offset, m.bit_length) for m in slave.outputs_map]
            self._default_outputs = layout == list(_DEFAULT_OUTPUTS)

    def on_sync0(self, slave: Slave, t: float) -> None:
        """Counts SYNC0 pulses (DC tests)."""
        self.sync0_count += 1


def create_io_slave(clock: Clock, name: str = "GL-IO 8DIO 2AIO", serial: int = 0,
                    foe: FoeHandler | None = None, revision: int = 1) -> Slave:
    """An ``ethercat_io`` slave ready to be put in a segment."""
    return Slave(clock, io_description(name, serial, revision), IoApplication(), foe, name=name)
