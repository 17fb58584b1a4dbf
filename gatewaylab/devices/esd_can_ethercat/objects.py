"""The esd CAN-EtherCAT's description and object dictionary (manual 5.1.2-5.1.5).

:func:`esd_description` is the one :class:`~gatewaylab.ethercat.description.DeviceDescription`
behind the SII, the ESI and the dictionary: identity of 5.1.3 (vendor 0x17, product 2, device
type 0x13881389, 0x1008 "MEESC"), the default process data of 4.2 (0x1600 -> 198 B outputs,
0x1A00 -> 168 B inputs, the optional 0x1A85 CAN status PDO), a bootstrap mailbox with the same
SM0/SM1 layout as the standard one. :func:`resize_queues` makes the queue objects and the fixed
mapping objects follow 0x8000 (5.1.3.7, 5.1.3.8, 5.1.5.5).
"""

from __future__ import annotations

from dataclasses import replace

from gatewaylab.devices.esd_can_ethercat.codec import RX_SIZE, TX_SIZE, input_size, output_size
from gatewaylab.ethercat.description import DeviceDescription, Pdo, PdoEntry
from gatewaylab.od import Access, DataType, ObjectDictionary

__all__ = [
    "BOOTLOADER_VERSION",
    "DEFAULT_LOCAL_QUEUE",
    "DEFAULT_QUEUE",
    "DEVICE_NAME",
    "DEVICE_TYPE",
    "F108",
    "F800_SUB0",
    "FLAG_29BIT",
    "HARDWARE_VERSION",
    "INPUTS_START",
    "MAILBOX_IN",
    "MAILBOX_OUT",
    "ORDER_CODE",
    "OUTPUTS_START",
    "PRODUCT_CODE",
    "PRODUCT_NAME",
    "RAM_END",
    "REVISION",
    "SOFTWARE_VERSION",
    "STATISTICS",
    "STATISTICS_SUB0",
    "STATUS_PDO",
    "STATUS_PDO_BYTES",
    "VENDOR_ID",
    "add_esd_objects",
    "esd_description",
    "max_rx_queue",
    "max_tx_queue",
    "resize_queues",
    "status_pdo",
]


VENDOR_ID = 0x00000017          # 5.1.3.5: esd
PRODUCT_CODE = 0x00000002       # 5.1.3.5: CAN-EtherCAT
REVISION = 0x00000001           # 5.1.3.5: ESI revision (= the SII's)
DEVICE_TYPE = 0x13881389        # 5.1.3.1: module profile 5000, CoE profile 5001
DEVICE_NAME = "MEESC"           # 5.1.3.2
HARDWARE_VERSION = "1.2"        # 5.1.3.3 (Figure 31)
SOFTWARE_VERSION = "2.3"        # 5.1.3.4 (this manual: "Firmware version from Version 2.3")
BOOTLOADER_VERSION = "U-Boot 2010.06"  # 7.7: the bootloader is U-Boot
PRODUCT_NAME = "CAN-EtherCAT"
ORDER_CODE = "C.2922.02"

MAILBOX_OUT = (0x1000, 128)     # Figure 14/15: SM0 128 MbxOut, SM1 128 MbxIn
MAILBOX_IN = (0x1080, 128)
OUTPUTS_START = 0x1100
INPUTS_START = 0x1800
RAM_END = 0x2000                # the ESC's 8 KiB (4 KiB process RAM after the registers)
STATUS_PDO_BYTES = 6            # 0x1A85: 48 bits

DEFAULT_QUEUE = 16              # 0x8000:21 / :22 default 10h
DEFAULT_LOCAL_QUEUE = 1000      # 0x8000:23 / :24 default 03E8h
FLAG_29BIT = 0x0001             # 0x8000:20 bit 0 (the manual leaves it unnamed; docs/decisions.md)

# 0x8000 subindexes (5.1.5.5)
NODE_ADDRESS, FLAGS, RX_QUEUE, TX_QUEUE, LOCAL_RX, LOCAL_TX = 0x01, 0x20, 0x21, 0x22, 0x23, 0x24

#: 0x2010 'Statistics' (5.1.4.2): subindex -> name (0x20/0x21 UINT8, the rest UINT32).
STATISTICS = {
    0x01: "Reset", 0x02: "Cyclic handler time (min.)", 0x03: "Cyclic handler time (max.)",
    0x04: "Cyclic handler time (avg.)", 0x05: "CAN handler time (min.)", 0x06: "CAN handler time (max.)",
    0x07: "CAN handler time (avg.)", 0x08: "Watchdog triggered",
    0x10: "EoE Frames EtherCAT Rx", 0x11: "EoE Frames EtherCAT Tx", 0x12: "EoE Frames EtherCAT Tx Error",
    0x13: "EoE Frames EtherCAT Tx Overrun", 0x14: "EoE Frames Local Rx", 0x15: "EoE Frames Local Tx",
    0x16: "EoE Frames Local Tx Error", 0x20: "App. CPU Usage (User)", 0x21: "App. CPU Usage (System)",
    0x30: "CAN Frames TX Requested", 0x31: "CAN Frames TX", 0x32: "CAN Frames RX",
    0x34: "CANDriver Controller overrun", 0x35: "CANDriver FIFO overrun", 0x36: "CANDriver Error Frames",
    0x37: "CANDriver Aborted Frames", 0x38: "CANDriver RX Frames", 0x39: "CANDriver RX RTR Frames",
    0x3A: "CANDriver RX Frames Ext.", 0x3B: "CANDriver RX RTR Frames Ext.", 0x3C: "CANDriver TX Frames",
    0x3D: "CANDriver TX RTR Frames", 0x3E: "CANDriver TX Frames Ext.", 0x3F: "CANDriver TX RTR Frames Ext.",
}
#: 5.1.4.2: "Number of sub-indexes 33" (the count of entries, as the manual gives it).
STATISTICS_SUB0 = 33

#: 0xF108 'CAN Status' (5.1.5.8): subindex -> (name, type); BIT2/BIT8 reserved entries as UINT8.
F108 = {
    0x01: ("Bus OFF", DataType.BOOLEAN), 0x02: ("Warning Limit reached", DataType.BOOLEAN),
    0x03: ("Rx overflow", DataType.BOOLEAN), 0x04: ("Reserved", DataType.BOOLEAN),
    0x05: ("Tx overflow", DataType.BOOLEAN), 0x06: ("Ack error", DataType.BOOLEAN),
    0x07: ("Reserved", DataType.UNSIGNED8), 0x08: ("Reserved", DataType.UNSIGNED8),
    0x11: ("Reserved (by esd)", DataType.BOOLEAN), 0x12: ("Reserved (by esd)", DataType.BOOLEAN),
    0x13: ("Reserved (by esd)", DataType.BOOLEAN), 0x14: ("Reserved (by esd)", DataType.BOOLEAN),
    0x21: ("Rx error counter", DataType.UNSIGNED8), 0x22: ("Tx error counter", DataType.UNSIGNED8),
}
#: 0x1A85 (5.1.3.9): F108 entries and the paddings between them (index 0 = padding).
STATUS_PDO = (
    (0xF108, 0x01, 1), (0xF108, 0x02, 1), (0xF108, 0x03, 1), (0, 0, 1), (0xF108, 0x05, 1), (0xF108, 0x06, 1),
    (0, 0, 10), (0xF108, 0x11, 1), (0xF108, 0x12, 1), (0xF108, 0x13, 1), (0xF108, 0x14, 1), (0, 0, 12),
    (0xF108, 0x21, 8), (0xF108, 0x22, 8),
)
#: 0xF800 (5.1.5.9, Figure 13: subindex 0 reads 24).
F800_SUB0 = 24
BAUD_INDEX, API_BAUD = 0x02, 0x05


def max_tx_queue(extended: bool) -> int:
    """Largest 0x8000:22: the outputs must fit SM2's room and 0x1600 holds at most 255 entries."""
    return min(255 - 3, (INPUTS_START - OUTPUTS_START - output_size(extended, 0)) // TX_SIZE[extended])


def max_rx_queue(extended: bool) -> int:
    """Largest 0x8000:21: the inputs (and the 6 B status PDO) must fit SM3's room; 0x1A00 <= 255 entries."""
    room = RAM_END - INPUTS_START - STATUS_PDO_BYTES - input_size(extended, 0)
    return min(255 - 4, room // RX_SIZE[extended])


def _queue_pdos(extended: bool, rx: int, tx: int) -> tuple[Pdo, Pdo]:
    out_index, in_index = (0x7001, 0x6001) if extended else (0x7000, 0x6000)
    u16 = DataType.UNSIGNED16
    rx_pdo = Pdo(0x1600, "CAN RxPDO-Map", (
        PdoEntry(out_index, 1, 16, "Tx Counter", u16), PdoEntry(out_index, 2, 16, "Rx Counter", u16),
        PdoEntry(out_index, 3, 16, "Number of Tx Messages", u16),
        *(PdoEntry(out_index, 4 + i, 8 * TX_SIZE[extended], f"Tx Message {i + 1}", DataType.OCTET_STRING)
          for i in range(tx))))
    tx_pdo = Pdo(0x1A00, "CAN TxPDO-Map", (
        PdoEntry(in_index, 1, 16, "Tx Counter", u16), PdoEntry(in_index, 2, 16, "Rx Counter", u16),
        PdoEntry(in_index, 3, 16, "Number of Rx Messages", u16),
        PdoEntry(in_index, 4, 16, "Tx Transaction Number", u16),
        *(PdoEntry(in_index, 5 + i, 8 * RX_SIZE[extended], f"Rx Message {i + 1}", DataType.OCTET_STRING)
          for i in range(rx))))
    return rx_pdo, tx_pdo


def status_pdo() -> Pdo:
    """0x1A85 'CAN Status PDO' (5.1.3.9): F108 with paddings of 1, 10 and 12 bits."""
    entries = []
    for index, sub, bits in STATUS_PDO:
        if index:
            name, dtype = F108[sub]
            entries.append(PdoEntry(index, sub, bits, name, dtype))
        else:
            entries.append(PdoEntry(0, 0, bits, f"Padding ({bits} Bit)"))
    return Pdo(0x1A85, "CAN Status PDO", tuple(entries))


def esd_description(serial: int = 0, name: str = PRODUCT_NAME) -> DeviceDescription:
    """The gateway as SII, ESI and dictionary show it (default queues: 11-bit, 16 + 16)."""
    rx_pdo, tx_pdo = _queue_pdos(False, DEFAULT_QUEUE, DEFAULT_QUEUE)
    return DeviceDescription(
        name=name, vendor_id=VENDOR_ID, product_code=PRODUCT_CODE, revision=REVISION, serial=serial,
        vendor_name="esd electronic system design gmbh", group="esd CAN gateways", order_code=ORDER_CODE,
        hardware_version=HARDWARE_VERSION, software_version=SOFTWARE_VERSION,
        mailbox_out=MAILBOX_OUT, mailbox_in=MAILBOX_IN, outputs_start=OUTPUTS_START, inputs_start=INPUTS_START,
        rx_pdos=(rx_pdo,), tx_pdos=(tx_pdo, status_pdo()), rx_assign=(0x1600,), tx_assign=(0x1A00,),
        bootstrap=True, bootstrap_mailbox=(*MAILBOX_OUT, *MAILBOX_IN), device_type=DEVICE_TYPE,
        extend_od=add_esd_objects)


def _read_only(od: ObjectDictionary, index: int) -> None:
    for entry in list(od.objects[index].entries.values()):
        od.replace_entry(replace(entry, access=Access.RO, preop_only=False, high=None))


def _set_sub0(od: ObjectDictionary, index: int, value: int) -> None:
    sub0 = od.objects[index].entries[0]
    od.replace_entry(replace(sub0, default=value))
    od.values[(index, 0)] = value


def add_esd_objects(od: ObjectDictionary) -> None:
    """The objects of 5.1.2 beyond the standard ones ``build_od`` makes (called by it)."""
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    ro, rw = Access.RO, Access.RW
    od.replace_entry(replace(od.entry(0x1008, 0), default=DEVICE_NAME))
    od.values[(0x1008, 0)] = DEVICE_NAME
    for index in (0x1600, 0x1A00, 0x1A85):  # 5.1.3.7-5.1.3.9: fixed mappings (RO), following 0x8000
        _read_only(od, index)
    od.add_record(0x2000, "Other Settings")
    od.add_sub(0x2000, 1, "EoE IP Port local mode", DataType.BOOLEAN, rw, 0, preop_only=True)
    od.add_sub(0x2000, 2, "Custom LED state", u8, rw, 0)
    od.add_record(0x2010, "Statistics")
    for sub, name in STATISTICS.items():
        od.add_sub(0x2010, sub, name, u8 if sub in (0x20, 0x21) else u32, rw if sub == 1 else ro, 0)
    _set_sub0(od, 0x2010, STATISTICS_SUB0)
    for extended in (False, True):
        in_index, out_index = (0x6001, 0x7001) if extended else (0x6000, 0x7000)
        bits = "29bit" if extended else "11bit"
        od.add_record(in_index, f"CAN {bits} Rx message queue")
        for sub, name in ((1, "Tx Counter Gateway"), (2, "Rx Counter Gateway"), (3, "Number of Rx Messages"),
                          (4, "Tx Transaction Number")):
            od.add_sub(in_index, sub, name, u16, ro, 0, pdo_mappable=True)
        od.add_record(out_index, f"CAN {bits} Tx message queue")
        for sub, name in ((1, "Tx Counter Application"), (2, "Rx Counter Application"),
                          (3, "Number of Tx Messages")):
            od.add_sub(out_index, sub, name, u16, rw, 0, pdo_mappable=True)
    od.add_record(0x8000, "CAN Interface configuration")
    for sub, name, dtype, value in ((NODE_ADDRESS, "Node Address", u16, 0), (FLAGS, "Flags", u16, 0),
                                    (RX_QUEUE, "Rx queue size", u8, DEFAULT_QUEUE),
                                    (TX_QUEUE, "Tx queue size", u8, DEFAULT_QUEUE),
                                    (LOCAL_RX, "Local Rx queue size", u16, DEFAULT_LOCAL_QUEUE),
                                    (LOCAL_TX, "Local Tx queue size", u16, DEFAULT_LOCAL_QUEUE)):
        od.add_sub(0x8000, sub, name, dtype, rw, value, preop_only=sub != NODE_ADDRESS)
    od.add_array(0x8001, "CAN filter table", DataType.UNSIGNED64, 255, rw, 0, sub0_access=rw, sub0_default=0,
                 sub_names=[f"Identifier Area {i}" for i in range(1, 256)])
    od.add_record(0xF000, "Modular Device Profile")
    for sub, name, dtype, value in ((1, "Index distance", u16, 16), (2, "Maximum number of modules", u16, 1),
                                    (3, "General configuration", u32, 1)):
        od.add_sub(0xF000, sub, name, dtype, ro, value)
    od.add_record(0xF108, "CAN Status")
    for sub, (name, dtype) in F108.items():
        od.add_sub(0xF108, sub, name, dtype, ro, 0, pdo_mappable=True)
    od.add_record(0xF800, "CAN Bus Parameter Set")
    od.add_sub(0xF800, BAUD_INDEX, "Baud rate", u8, rw, 0xFF)
    od.add_sub(0xF800, API_BAUD, "API-baud rate", u32, rw, 0x7FFFFFFF)
    _set_sub0(od, 0xF800, F800_SUB0)
    resize_queues(od, False, DEFAULT_QUEUE, DEFAULT_QUEUE)


def _resize(od: ObjectDictionary, index: int, first: int, count: int, name: str, dtype: DataType,
            access: Access, default: object, *, pdo_mappable: bool = False, preop_only: bool = False) -> None:
    """Entries ``first .. first+count-1`` exist afterwards (named ``name i``), none beyond them."""
    obj = od.objects[index]
    last = first + count - 1
    for sub in [s for s in obj.entries if s > last]:
        del obj.entries[sub]
        del od.entries[(index, sub)]
        del od.values[(index, sub)]
    for i in range(count):
        sub = first + i
        if sub not in obj.entries:
            od.add_sub(index, sub, f"{name} {i + 1}", dtype, access, default, pdo_mappable=pdo_mappable,
                       preop_only=preop_only)
    _set_sub0(od, index, max(obj.entries))


def resize_queues(od: ObjectDictionary, extended: bool, rx: int, tx: int) -> None:
    """0x6000/0x6001 with ``rx`` Rx messages, 0x7000/0x7001 with ``tx`` Tx messages, and the
    mappings 0x1600 (Tx counter, Rx counter, NumTx, Tx messages of 0x700z) and 0x1A00 (counters,
    NumRx, Tx transaction number, Rx messages of 0x600z) for the identifier mode (5.1.3.7/8)."""
    for ext in (False, True):
        in_index, out_index = (0x6001, 0x7001) if ext else (0x6000, 0x7000)
        _resize(od, in_index, 5, rx, "Rx Message", DataType.OCTET_STRING, Access.RO, bytes(RX_SIZE[ext]),
                pdo_mappable=True)
        _resize(od, out_index, 4, tx, "Tx Message", DataType.OCTET_STRING, Access.RW, bytes(TX_SIZE[ext]),
                pdo_mappable=True, preop_only=True)
    rx_pdo, tx_pdo = _queue_pdos(extended, rx, tx)
    for pdo in (rx_pdo, tx_pdo):
        _resize(od, pdo.index, 1, len(pdo.entries), "SubIndex", DataType.UNSIGNED32, Access.RO, 0)
        for sub, entry in enumerate(pdo.entries, start=1):
            e = od.entry(pdo.index, sub)
            od.replace_entry(replace(e, name=f"SubIndex {sub:03d}", default=entry.mapping))
            od.values[(pdo.index, sub)] = entry.mapping
