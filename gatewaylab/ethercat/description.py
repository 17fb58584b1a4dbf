"""Device description: everything a slave shows a master (identity, mailbox, SMs, PDOs, objects).

One frozen description feeds the SII EEPROM image (``sii.py``), the standard CoE objects
(``slave.py``) and the ESI XML (``esi.py``), so the three can never disagree. The ECAN-Lite and
esd CAN-EtherCAT devices build their own description and add device objects with ``objects``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from .errors import EtherCATConfigError
from .od import Access, DataType, ObjectDictionary


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

    @property
    def bit_length(self) -> int:
        return sum(e.bit_length for e in self.entries)


def _assigned(pdos: tuple[Pdo, ...], assign: tuple[int, ...] | None) -> tuple[Pdo, ...]:
    if assign is None:
        return pdos
    by_index = {p.index: p for p in pdos}
    return tuple(by_index[i] for i in assign)


@dataclass(frozen=True, slots=True)
class ObjectDef:
    """A device object added to the dictionary: VAR when ``subs`` is empty, else a RECORD."""

    index: int
    name: str
    data_type: DataType = DataType.UNSIGNED8
    value: int | float | str | bytes = 0
    access: Access = Access.RO
    subs: tuple[tuple[str, DataType, int | float | str | bytes, Access], ...] = ()


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
    device_type: int = 0x00000000
    objects: tuple[ObjectDef, ...] = ()
    #: Further device-specific dictionary setup (hooks on entries, arrays...).
    extend_od: Callable[[ObjectDictionary], None] | None = field(default=None, compare=False)

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
        return _assigned(self.rx_pdos, self.rx_assign)

    @property
    def assigned_tx_pdos(self) -> tuple[Pdo, ...]:
        return _assigned(self.tx_pdos, self.tx_assign)

    @property
    def output_bytes(self) -> int:
        """Outputs (SM2) size with the default assignment."""
        return (sum(p.bit_length for p in self.assigned_rx_pdos) + 7) // 8

    @property
    def input_bytes(self) -> int:
        return (sum(p.bit_length for p in self.assigned_tx_pdos) + 7) // 8

    @property
    def mailbox_protocols(self) -> int:
        """SII word 0x1C: bit 2 CoE, bit 3 FoE."""
        return (0x04 if self.coe else 0) | (0x08 if self.foe else 0)

    # SyncManager control bytes the master must program (ET1100 0x0804).
    SM0_CONTROL = 0x26  # mailbox, ECAT writes, PDI interrupt
    SM1_CONTROL = 0x22  # mailbox, ECAT reads, PDI interrupt
