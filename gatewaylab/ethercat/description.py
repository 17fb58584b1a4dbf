"""Device description: everything a slave shows a master (identity, mailbox, SMs, PDOs, objects).

One frozen description feeds the SII EEPROM image (``sii.py``), the object dictionary
(:func:`build_od`: standard CoE objects plus the device's) and the ESI XML (``esi.py``), so the
three can never disagree. The ECAN-Lite and esd CAN-EtherCAT devices build their own description
and add device objects with ``objects``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.od import Access, DataType, Entry, ObjectCode, ObjectDictionary, SdoAbort, SdoAbortCode

__all__ = ["DeviceDescription", "ObjectDef", "Pdo", "PdoEntry", "add_pdo_checks", "build_od"]


@dataclass(frozen=True, slots=True)
class PdoEntry:
    """One mapped object; index 0 is a gap of ``bit_length`` bits."""

    index: int
    subindex: int
    bit_length: int
    name: str
    data_type: DataType = DataType.UNSIGNED8

    @property
    def mapping(self) -> int:
        """The 32-bit value of a mapping entry: index << 16 | sub << 8 | bit length."""
        return (self.index << 16) | (self.subindex << 8) | self.bit_length


@dataclass(frozen=True, slots=True)
class Pdo:
    """A PDO (0x1600.. RxPDO = outputs, 0x1A00.. TxPDO = inputs)."""

    index: int
    name: str
    entries: tuple[PdoEntry, ...]
    #: A fixed PDO: its mapping object is read-only (ESI ``Fixed="1"``).
    fixed: bool = False
    #: PDOs that cannot be assigned together with this one (ESI ``<Exclude>``, e.g. alternatives
    #: mapping the same objects).
    exclude: tuple[int, ...] = ()

    @property
    def bit_length(self) -> int:
        """Bits of all its entries."""
        return sum(e.bit_length for e in self.entries)


def _assigned(pdos: tuple[Pdo, ...], assign: tuple[int, ...] | None) -> tuple[Pdo, ...]:
    if assign is None:
        return pdos
    by_index = {p.index: p for p in pdos}
    return tuple(by_index[i] for i in assign)


@dataclass(frozen=True, slots=True)
class ObjectDef:
    """A device object added to the dictionary: VAR when ``subs`` is empty, else a RECORD.

    ``pdo_mappable`` applies to the VAR or to every entry of the RECORD; the direction follows the
    access (RO: TxPDO, RWW: RxPDO, RW: both). ``preop_only``: writable in PREOP only.
    """

    index: int
    name: str
    data_type: DataType = DataType.UNSIGNED8
    value: int | float | str | bytes = 0
    access: Access = Access.RO
    subs: tuple[tuple[str, DataType, int | float | str | bytes, Access], ...] = ()
    pdo_mappable: bool = False
    preop_only: bool = False
    #: Subindexes of ``subs`` when they are not 1, 2, 3 ... (a record with gaps, e.g. ECAN-Lite
    #: 0x8001 has no subindex 35); empty = numbered from 1.
    sub_indexes: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class DeviceDescription:
    """Identity, mailbox and process data layout of one slave type."""

    name: str
    vendor_id: int
    product_code: int
    revision: int = 1
    serial: int = 0
    vendor_name: str = "gatewaylab"
    group: str = "gatewaylab"
    order_code: str = ""
    hardware_version: str = "1.0"
    software_version: str = "1.0"
    mailbox_out: tuple[int, int] = (0x1000, 128)  # SM0: master -> slave (start, size)
    mailbox_in: tuple[int, int] = (0x1080, 128)  # SM1: slave -> master
    outputs_start: int = 0x1100  # SM2
    inputs_start: int = 0x1400  # SM3
    #: Process data SM control bytes (ET1100 0x0804): 0x64 = 3-buffer, ECAT writes, watchdog
    #: trigger; 0x20 = 3-buffer, ECAT reads. 1-buffer (handshake) layouts use 0x66 / 0x22.
    outputs_control: int = 0x64
    inputs_control: int = 0x20
    #: SII/ESI default SM2/SM3 sizes when they differ from the default assignment's (ECAN-Lite
    #: 5.3: 3072 B in the SII while 0x1C12/0x1C13 assign 8 chunks); None = the assignment's size.
    outputs_sm_size: int | None = None
    inputs_sm_size: int | None = None
    rx_pdos: tuple[Pdo, ...] = ()
    tx_pdos: tuple[Pdo, ...] = ()
    #: PDO indexes assigned by default (0x1C12 / 0x1C13); None = all of them. A master may assign
    #: others (e.g. the first N of ECAN-Lite's 24 chunk PDOs) in PREOP.
    rx_assign: tuple[int, ...] | None = None
    tx_assign: tuple[int, ...] | None = None
    coe: bool = True
    foe: bool = True
    bootstrap: bool = False
    bootstrap_mailbox: tuple[int, int, int, int] = (0x1000, 512, 0x1200, 512)
    dc: bool = True
    #: ESI ``<Dc><OpMode>`` rows: (name, description, AssignActivate); 0 = no SYNC signal.
    dc_op_modes: tuple[tuple[str, str, int], ...] = (("SM", "SM-Synchron", 0), ("DC", "DC-Synchron", 0x300))
    device_type: int = 0x00000000
    objects: tuple[ObjectDef, ...] = ()
    #: Further device-specific dictionary setup (hooks on entries, arrays...).
    extend_od: Callable[[ObjectDictionary], None] | None = field(default=None, compare=False)
    #: Mailbox protocols declared besides CoE/FoE, SII word 0x1C bits (0x01 AoE, 0x02 EoE, 0x10 SoE,
    #: 0x20 VoE): not emulated, a request answers with the mailbox error "unsupported protocol".
    other_protocols: int = 0
    #: SII General category CoE details; None = SDO, SDO info, PDO assign/config, complete access.
    coe_details: int | None = None
    #: SII words 0..6 (ESI ``<Eeprom><ConfigData>``); None = gatewaylab's default PDI configuration.
    sii_config: bytes | None = None
    #: EEPROM size in bytes (ESI ``<Eeprom><ByteSize>``); None = the smallest that holds the categories.
    eeprom_bytes: int | None = None
    #: Further SII categories (type, data) written after the PDO categories (ESI ``<Eeprom><Category>``).
    sii_categories: tuple[tuple[int, bytes], ...] = ()
    #: The SII byte for byte (ESI ``<Eeprom><Data>`` or a dump); None = built from the description.
    sii_image: bytes | None = None
    #: A device without mailbox and outputs whose inputs SyncManager is SM0 (the ESI's ``<Sm>`` order, an
    #: EL1008's); the SII then lists that one SyncManager.
    inputs_first: bool = False

    def __post_init__(self) -> None:
        for start, size in (self.mailbox_out, self.mailbox_in):
            if start < 0x1000 or size < 16:
                raise EtherCATConfigError(f"{self.name}: mailbox at 0x{start:04X} size {size} is impossible")
        if not self.name:
            raise EtherCATConfigError("a device needs a name")
        for pdos, assign in ((self.rx_pdos, self.rx_assign), (self.tx_pdos, self.tx_assign)):
            known = {p.index for p in pdos}
            if assign is not None and not set(assign) <= known:
                raise EtherCATConfigError(f"{self.name}: assignment {assign} names PDOs that do not exist")

    @property
    def assigned_rx_pdos(self) -> tuple[Pdo, ...]:
        """RxPDOs assigned by default (0x1C12)."""
        return _assigned(self.rx_pdos, self.rx_assign)

    @property
    def assigned_tx_pdos(self) -> tuple[Pdo, ...]:
        """TxPDOs assigned by default (0x1C13)."""
        return _assigned(self.tx_pdos, self.tx_assign)

    @property
    def output_bytes(self) -> int:
        """Outputs (SM2) size with the default assignment."""
        return (sum(p.bit_length for p in self.assigned_rx_pdos) + 7) // 8

    @property
    def input_bytes(self) -> int:
        """Inputs (SM3) size with the default assignment."""
        return (sum(p.bit_length for p in self.assigned_tx_pdos) + 7) // 8

    @property
    def outputs_sii_size(self) -> int:
        """SM2 default size in the SII and ESI."""
        return self.output_bytes if self.outputs_sm_size is None else self.outputs_sm_size

    @property
    def inputs_sii_size(self) -> int:
        """SM3 default size in the SII and ESI."""
        return self.input_bytes if self.inputs_sm_size is None else self.inputs_sm_size

    @property
    def mailbox_protocols(self) -> int:
        """SII word 0x1C: bit 2 CoE, bit 3 FoE (and ``other_protocols``)."""
        return (0x04 if self.coe else 0) | (0x08 if self.foe else 0) | self.other_protocols

    @property
    def has_mailbox(self) -> bool:
        """SM0/SM1 are mailboxes: some mailbox protocol is declared."""
        return self.coe or self.foe or bool(self.other_protocols)

    @property
    def sm_numbers(self) -> tuple[int, int]:
        """(outputs, inputs) process data SyncManager numbers: 2/3 behind a mailbox, else 0/1, or 1/0 for an
        inputs-only device whose inputs are SM0 (``inputs_first``)."""
        if self.has_mailbox:
            return 2, 3
        return (1, 0) if self.inputs_first else (0, 1)

    # SyncManager control bytes the master must program (ET1100 0x0804).
    SM0_CONTROL = 0x26  # mailbox, ECAT writes, PDI interrupt
    SM1_CONTROL = 0x22  # mailbox, ECAT reads, PDI interrupt


def _mapping_validators(od: ObjectDictionary, index: int, rx: bool, assignment: bool) -> None:
    """PDO mapping / assignment objects: entries may only change while subindex 0 is 0, mapping
    entries must name a mappable object of the right direction and size (0x06040041), assignments
    an existing PDO of the right range (0x06090030) (ETG.1000.6 PDO configuration; QEC A.5)."""

    def check_mapping(value: int) -> None:
        target, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        if target == 0:
            return  # a gap of ``bits`` bits
        try:
            entry = od.entry(target, sub)
        except SdoAbort:
            raise SdoAbort(SdoAbortCode.OBJECT_NOT_MAPPABLE, f"0x{target:04X}:{sub} does not exist") from None
        mappable = entry.rx_pdo if rx else entry.tx_pdo
        length = od.bit_length(target, sub)
        if entry.data_type is DataType.BOOLEAN and bits == 1:
            length = 1  # a BOOL maps as one bit (ETG.2000 BOOL BitSize 1)
        if not mappable or length != bits:
            raise SdoAbort(SdoAbortCode.OBJECT_NOT_MAPPABLE, f"0x{target:04X}:{sub} cannot be mapped as {bits} bits")

    def check_assignment(value: int) -> None:
        lo = 0x1600 if rx else 0x1A00
        if not lo <= value < lo + 0x200 or value not in od:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, f"no PDO 0x{value:04X} to assign")

    def validator(entry: Entry, value: Any) -> None:
        if entry.subindex == 0:
            return
        if od.values[(index, 0)] != 0:
            raise SdoAbort(SdoAbortCode.SUBINDEX_CANNOT_BE_WRITTEN, "subindex 0 must be 0 to change the mapping")
        if assignment:
            check_assignment(int(value))
        else:
            check_mapping(int(value))

    od.add_validator(index, validator)


def add_pdo_checks(od: ObjectDictionary, desc: DeviceDescription) -> None:
    """The checks :func:`build_od` puts on the PDO mapping and assignment objects of ``desc`` (validators:
    a dictionary copied with ``od.copy()`` has none and gets its own here)."""
    for pdos, assign in ((desc.rx_pdos, 0x1C12), (desc.tx_pdos, 0x1C13)):
        for pdo in pdos:
            _mapping_validators(od, pdo.index, assign == 0x1C12, assignment=False)
        _mapping_validators(od, assign, assign == 0x1C12, assignment=True)


def _record(od: ObjectDictionary, index: int, name: str,
            entries: list[tuple[int, str, DataType, Any, Access]], *, pdo_mappable: bool = False,
            preop_only: bool = False, code: ObjectCode = ObjectCode.RECORD) -> None:
    """A RECORD whose subindex 0 ("SubIndex 000", as CoE masters show it) holds the highest subindex."""
    od.add_record(index, name, code)
    for sub, ename, dtype, value, access in entries:
        od.add_sub(index, sub, ename, dtype, access, value, pdo_mappable=pdo_mappable, preop_only=preop_only,
                   sub0_name="SubIndex 000")


def build_od(desc: DeviceDescription) -> ObjectDictionary:
    """The slave's dictionary: standard communication objects (0x1000..0x1C33) from the
    description, then the device objects, then ``desc.extend_od`` (hooks, arrays)."""
    od = ObjectDictionary()
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    ro = Access.RO
    od.add_variable(0x1000, "Device type", u32, ro, desc.device_type)
    od.add_variable(0x1008, "Manufacturer device name", DataType.VISIBLE_STRING, ro, desc.name)
    od.add_variable(0x1009, "Manufacturer hardware version", DataType.VISIBLE_STRING, ro, desc.hardware_version)
    od.add_variable(0x100A, "Manufacturer software version", DataType.VISIBLE_STRING, ro, desc.software_version)
    _record(od, 0x1018, "Identity", [
        (1, "Vendor ID", u32, desc.vendor_id, ro), (2, "Product code", u32, desc.product_code, ro),
        (3, "Revision", u32, desc.revision, ro), (4, "Serial number", u32, desc.serial, ro)])
    types = [1, 2, 3, 4] if desc.has_mailbox else [4] if desc.inputs_first else [3, 4]
    od.add_array(0x1C00, "Sync manager type", u8, len(types), ro, defaults=types, sub0_name="SubIndex 000",
                 sub_names=[f"SubIndex {i:03d}" for i in range(1, len(types) + 1)])
    for pdos, assigned, assign in ((desc.rx_pdos, desc.assigned_rx_pdos, 0x1C12),
                                   (desc.tx_pdos, desc.assigned_tx_pdos, 0x1C13)):
        for pdo in pdos:
            n = max(8, len(pdo.entries))
            access = Access.RO if pdo.fixed else Access.RW
            od.add_array(pdo.index, pdo.name, u32, n, access, defaults=[e.mapping for e in pdo.entries],
                         sub0_access=access, sub0_default=len(pdo.entries), preop_only=True,
                         sub0_name="SubIndex 000", sub_names=[f"SubIndex {i:03d}" for i in range(1, n + 1)])
        n = max(4, len(pdos))
        od.add_array(assign, "RxPDO assign" if assign == 0x1C12 else "TxPDO assign", u16, n, Access.RW,
                     defaults=[p.index for p in assigned], sub0_access=Access.RW, sub0_default=len(assigned),
                     preop_only=True, sub0_name="SubIndex 000",
                     sub_names=[f"SubIndex {i:03d}" for i in range(1, n + 1)])
    add_pdo_checks(od, desc)
    for index, name in ((0x1C32, "SM output parameter"), (0x1C33, "SM input parameter")):
        od.add_record(index, name)
        od.add_sub(index, 1, "Sync mode", u16, Access.RW, 1, preop_only=True, sub0_name="SubIndex 000")
        for sub, ename, dtype, value in ((2, "Cycle time", u32, 1_000_000), (3, "Shift time", u32, 0),
                                         (4, "Sync modes supported", u16, 0x0007),
                                         (5, "Minimum cycle time", u32, 100_000),
                                         (6, "Calc and copy time", u32, 10_000),
                                         (9, "Delay time", u32, 0), (11, "SM event missed", u16, 0),
                                         (12, "Cycle time too small", u16, 0), (32, "Sync error", DataType.BOOLEAN, 0)):
            od.add_sub(index, sub, ename, dtype, ro, value)
    for o in desc.objects:
        if o.subs:
            numbers = o.sub_indexes or tuple(range(1, len(o.subs) + 1))
            _record(od, o.index, o.name, [(i, *sub) for i, sub in zip(numbers, o.subs, strict=True)],
                    pdo_mappable=o.pdo_mappable, preop_only=o.preop_only)
        else:
            od.add_variable(o.index, o.name, o.data_type, o.access, o.value, pdo_mappable=o.pdo_mappable,
                            preop_only=o.preop_only)
    if desc.extend_od is not None:
        desc.extend_od(od)
    return od
