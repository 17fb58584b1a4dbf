"""The EtherCAT master contract of the host libraries: the same calls in process and on a NIC.

The ECAN-Lite and esd host libraries, the python-can interfaces over them and ``gatewaylab ec``
talk to slaves through :class:`MasterBackend`. Two implementations exist:

* :class:`~gatewaylab.hosts.ethercat.inprocess.InProcessBackend` -- the in-process
  :class:`~gatewaylab.hosts.ethercat.master.Master` on a rig's segment (no root, simulated or real
  clock; ``InProcessBackend.from_rig(rig)``);
* :class:`~gatewaylab.hosts.ethercat.pysoem_backend.PysoemBackend` -- SOEM through pysoem on a network
  interface (root); an I/O adapter.

Rules both keep (docs/ethercat-host.md):

* a new backend has scanned the line and every slave is in PREOP (IgH's default state);
* ``config_map`` only maps (SyncManagers, FMMUs from the PDO assignment); the caller requests
  SAFEOP and OP with :meth:`~MasterBackend.request_state`, which keeps process data flowing
  while it waits, as a master must for SAFEOP -> OP;
* errors carry wire codes: :class:`~gatewaylab.od.SdoAbort` (abort code),
  :class:`~gatewaylab.ethercat.errors.AlStatusError` (AL status code),
  :class:`~gatewaylab.ethercat.errors.FoeError` (FoE error code), :class:`MasterTimeout`
  (no answer; both a gatewaylab error and the builtin :class:`TimeoutError`);
* host code waits with ``backend.clock.wait()``: on a simulated clock time passes only there.

This file holds the contract only (the Protocol and the values it speaks in); what the two
implementations share -- register access, the mailbox FoE port, the AL state wait -- is in
:mod:`gatewaylab.hosts.ethercat.shared`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.sii import SiiInfo

__all__ = ["EntryInfo", "MasterBackend", "MasterTimeout", "ObjectInfo", "ProgressFn", "SlaveIdentity"]

#: ``progress(done_bytes, total_bytes)``; total is 0 while unknown (an FoE read).
ProgressFn = Callable[[int, int], None]


class MasterTimeout(TimeoutError_, TimeoutError):
    """No answer in time: a gatewaylab error with the builtin's type, so ``except TimeoutError`` works."""


@dataclass(frozen=True, slots=True)
class SlaveIdentity:
    """One slave as ``gatewaylab ec slaves`` prints it: its place in the line and its SII identity."""

    position: int
    station: int
    name: str
    vendor_id: int
    product_code: int
    revision: int
    serial: int


@dataclass(frozen=True, slots=True)
class EntryInfo:
    """One subindex as SDO Information describes it (ETG.1000.6 entry description)."""

    subindex: int
    data_type: int
    bit_length: int
    access: int
    name: str


@dataclass(frozen=True, slots=True)
class ObjectInfo:
    """One object as SDO Information describes it (ETG.1000.6 object description) with its entries."""

    index: int
    object_code: int
    data_type: int
    max_subindex: int
    name: str
    entries: tuple[EntryInfo, ...]


@runtime_checkable
class MasterBackend(Protocol):
    """What the host libraries need of an EtherCAT master; the same calls in process and on a real NIC."""

    clock: Clock
    #: Cycles whose working counter differed from the expected one (every :meth:`exchange`).
    wkc_errors: int

    def slaves(self) -> list[SlaveIdentity]:
        """The slaves of the line by position, with the identity a host library checks."""
        ...

    def state(self, position: int) -> tuple[AlState, int]:
        """(AL state, AL status code) of one slave, to see where it is and why it refused."""
        ...

    def al_status(self, position: int) -> tuple[int, int]:
        """(raw AL status with the error flag, AL status code) of one slave."""
        ...

    def request_state(self, state: AlState, position: int | None = None, timeout: float = 5.0) -> AlState:
        """Move one slave (or every slave) to an AL state, raising AlStatusError with the code it refused with."""
        ...

    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes:
        """Read an object by CoE SDO."""
        ...

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes, complete: bool = False) -> None:
        """Write an object by CoE SDO."""
        ...

    def object_dictionary(self, position: int) -> list[ObjectInfo]:
        """Every object of the slave by SDO information, to browse it without an ESI."""
        ...

    def object_info(self, position: int, index: int) -> ObjectInfo:
        """One object by SDO information: name, entries, types."""
        ...

    def foe_read(self, position: int, name: str, password: int = 0, *, progress: ProgressFn | None = None) -> bytes:
        """Read a file by FoE (``progress`` is told the bytes so far)."""
        ...

    def foe_write(self, position: int, name: str, data: bytes, password: int = 0, *,
                  progress: ProgressFn | None = None) -> None:
        """Write a file by FoE (``progress`` is told the bytes so far)."""
        ...

    def sii_read(self, position: int) -> bytes:
        """The slave's SII image."""
        ...

    def reg_read(self, position: int, address: int, length: int) -> bytes:
        """Read ESC registers of one slave."""
        ...

    def reg_write(self, position: int, address: int, data: bytes) -> None:
        """Write ESC registers of one slave."""
        ...

    def sii_info(self, position: int) -> SiiInfo:
        """The parsed SII (mailboxes, SyncManagers, PDO categories) of one slave."""
        ...

    def config_map(self) -> int:
        """Map the process data of every slave; the image size."""
        ...

    def configure_dc(self, position: int, cycle_ns: int, shift_ns: int = 0) -> None:
        """Program DC SYNC0 of one slave."""
        ...

    def outputs(self, position: int) -> memoryview:
        """One slave's outputs in the image, written in place before :meth:`exchange`."""
        ...

    def inputs(self, position: int) -> bytes:
        """One slave's inputs as the last :meth:`exchange` brought them."""
        ...

    def exchange(self) -> tuple[int, int]:
        """One process data cycle: (working counter, the one expected)."""
        ...

    def close(self) -> None:
        """Release the line (socket, NIC, rig link)."""
        ...
