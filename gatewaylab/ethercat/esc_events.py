"""PDI events: what a master's access asked of the slave firmware, returned by the ESC as values.

The real ESC raises a PDI interrupt and sets AL event request bits (ET1100 0x0220: AL control,
SM change, SyncManager n); the firmware reads them after the access. The emulated ESC does the
same with values: :meth:`gatewaylab.ethercat.esc.Esc.process_datagram` returns these records and
the :class:`~gatewaylab.ethercat.slave.Slave` hands them to the application once the access is
over (the contract is in :mod:`gatewaylab.ethercat.esc`). Records without a payload are shared
instances (:data:`SM_CHANGED`; the ESC keeps one :class:`SmWritten` / :class:`SmRead` per running
SyncManager): the frame path allocates nothing for them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, TypeAlias

__all__ = ["SM_CHANGED", "AlControlRequested", "EscEvent", "SmChanged", "SmRead", "SmWritten"]


@dataclass(frozen=True, slots=True)
class SmWritten:
    """The master completed a buffer of a SyncManager it writes (mailbox out, outputs; 0x0220 bit
    8 + n): the firmware reads it from ``Esc.pdi_outputs[sm]``, as it reads the SyncManager's buffer
    on the interrupt (3-buffer mode: the newest complete buffer)."""

    sm: int


@dataclass(frozen=True, slots=True)
class SmRead:
    """The master read a SyncManager buffer it reads to its end (mailbox in, inputs): the firmware
    refills it (0x0220 bit 8 + n)."""

    sm: int


@dataclass(frozen=True, slots=True)
class AlControlRequested:
    """The master wrote AL control (0x0120; 0x0220 bit 0): the requested state and acknowledge bit."""

    control: int


@dataclass(frozen=True, slots=True)
class SmChanged:
    """The master wrote SyncManager registers (0x0220 bit 4, SM change): the firmware checks that
    its channels still run as it needs them."""


#: A PDI event of one access, in the order the ESC raised them.
EscEvent: TypeAlias = SmWritten | SmRead | AlControlRequested | SmChanged

#: The one SM-change event (no payload).
SM_CHANGED: Final = SmChanged()
