"""The ET1100 register map the emulated ESC implements: addresses, bit meanings, AL states, counters.

One table shared by every part of the ESC (memory, AL state machine, SII interface, distributed
clocks) and by masters that address the registers; :class:`EscStats` is what those parts count.
Register map and bit meanings follow the ET1100 hardware data sheet section II; the states follow
IDX guide 4.2 (tables 4-16..4-18).
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Final

__all__ = [
    "AL_ACK",
    "AL_ERROR",
    "AL_TRANSITIONS",
    "DL_STATUS_PDI_OPERATIONAL",
    "DL_STATUS_WD_OK",
    "FMMU_REG",
    "RAM_START",
    "REG_AL_CONTROL",
    "REG_AL_STATUS",
    "REG_AL_STATUS_CODE",
    "REG_DC_ACTIVATION",
    "REG_DC_RECV_TIME",
    "REG_DC_RECV_TIME_PU",
    "REG_DC_START_TIME",
    "REG_DC_SYNC0_CYCLE",
    "REG_DC_SYNC0_STATUS",
    "REG_DC_SYNC1_CYCLE",
    "REG_DC_SYSTEM_DELAY",
    "REG_DC_SYSTEM_OFFSET",
    "REG_DC_SYSTEM_TIME",
    "REG_DIGITAL_OUT",
    "REG_DIGITAL_OUT_END",
    "REG_DL_CONTROL",
    "REG_DL_STATUS",
    "REG_FEATURES",
    "REG_FMMU",
    "REG_PDI_CONTROL",
    "REG_RX_ERROR",
    "REG_SII_ADDRESS",
    "REG_SII_CONFIG",
    "REG_SII_CONTROL",
    "REG_SII_DATA",
    "REG_SM",
    "REG_STATION_ADDRESS",
    "REG_STATION_ALIAS",
    "REG_TYPE",
    "REG_WD_COUNTER_SM",
    "REG_WD_DIVIDER",
    "REG_WD_STATUS_SM",
    "REG_WD_TIME_PDI",
    "REG_WD_TIME_SM",
    "SII_BUSY",
    "SII_ERR_ACK",
    "SII_ERR_CHECKSUM",
    "SII_ERR_WRITE_ENABLE",
    "SII_READ8",
    "SII_TWO_ADDRESS_BYTES",
    "SM_ACT_ENABLE",
    "SM_ACT_REPEAT",
    "SM_CTRL_ECAT_WRITE",
    "SM_CTRL_MAILBOX",
    "SM_CTRL_WATCHDOG",
    "SM_PDI_DISABLE",
    "SM_PDI_REPEAT_ACK",
    "SM_REG",
    "SM_STATUS_FULL",
    "SM_STATUS_READ_EVENT",
    "SM_STATUS_WRITE_EVENT",
    "SYNC0_MIN_CYCLE_NS",
    "U8",
    "U16",
    "U32",
    "U64",
    "AlState",
    "EscStats",
    "SmConfig",
]


U8: Final = struct.Struct("<B")
U16: Final = struct.Struct("<H")
U32: Final = struct.Struct("<I")
U64: Final = struct.Struct("<Q")
FMMU_REG: Final = struct.Struct("<IHBBHBBB3x")
SM_REG: Final = struct.Struct("<HHBBBB")

# Register addresses (ET1100 data sheet section II).
REG_TYPE: Final = 0x0000
REG_FEATURES: Final = 0x0008
REG_STATION_ADDRESS: Final = 0x0010
REG_STATION_ALIAS: Final = 0x0012
REG_DL_CONTROL: Final = 0x0100
REG_DL_STATUS: Final = 0x0110
REG_AL_CONTROL: Final = 0x0120
REG_AL_STATUS: Final = 0x0130
REG_AL_STATUS_CODE: Final = 0x0134
REG_PDI_CONTROL: Final = 0x0140
REG_RX_ERROR: Final = 0x0300
REG_WD_DIVIDER: Final = 0x0400
REG_WD_TIME_PDI: Final = 0x0410
REG_WD_TIME_SM: Final = 0x0420
REG_WD_STATUS_SM: Final = 0x0440
REG_WD_COUNTER_SM: Final = 0x0442
REG_SII_CONFIG: Final = 0x0500
REG_SII_CONTROL: Final = 0x0502
REG_SII_ADDRESS: Final = 0x0504
REG_SII_DATA: Final = 0x0508
REG_FMMU: Final = 0x0600
REG_SM: Final = 0x0800
REG_DC_RECV_TIME: Final = 0x0900
REG_DC_SYSTEM_TIME: Final = 0x0910
REG_DC_RECV_TIME_PU: Final = 0x0918
REG_DC_SYSTEM_OFFSET: Final = 0x0920
REG_DC_SYSTEM_DELAY: Final = 0x0928
REG_DC_ACTIVATION: Final = 0x0981
REG_DC_SYNC0_STATUS: Final = 0x098E
REG_DC_START_TIME: Final = 0x0990
REG_DC_SYNC0_CYCLE: Final = 0x09A0
REG_DC_SYNC1_CYCLE: Final = 0x09A4
#: Digital I/O Output Data (ET1100 data sheet II, 0x0F00:0x0F03, ECAT r/w): the one register area a
#: process data SyncManager may cover (a digital output terminal's outputs, an EL2008's), see
#: :attr:`SmConfig.on_output_register`.
REG_DIGITAL_OUT: Final = 0x0F00
REG_DIGITAL_OUT_END: Final = 0x0F04
RAM_START: Final = 0x1000
#: Shortest SYNC0 period the emulated firmware follows (a shorter 0x09A0 is raised to it): a Python
#: PDI cannot take interrupts faster, and a 1 ns cycle would otherwise flood the clock (docs/decisions.md).
SYNC0_MIN_CYCLE_NS: Final = 10_000

AL_ERROR: Final = 0x10
AL_ACK: Final = 0x10
SII_BUSY: Final = 0x8000
SII_ERR_CHECKSUM: Final = 0x0800
SII_ERR_ACK: Final = 0x2000
SII_ERR_WRITE_ENABLE: Final = 0x4000
SII_READ8: Final = 0x0040
#: 0x0502 bit 7: EEPROM above 16 kbit, two address bytes (ET1100: bits 5..7 are read-only configuration)
SII_TWO_ADDRESS_BYTES: Final = 0x0080
SM_STATUS_FULL: Final = 0x08
SM_STATUS_WRITE_EVENT: Final = 0x01
SM_STATUS_READ_EVENT: Final = 0x02
SM_CTRL_MAILBOX: Final = 0x02
SM_CTRL_ECAT_WRITE: Final = 0x04
SM_CTRL_WATCHDOG: Final = 0x40
SM_ACT_ENABLE: Final = 0x01
SM_ACT_REPEAT: Final = 0x02
SM_PDI_DISABLE: Final = 0x01
SM_PDI_REPEAT_ACK: Final = 0x02
DL_STATUS_PDI_OPERATIONAL: Final = 0x0001
DL_STATUS_WD_OK: Final = 0x0002


class AlState(enum.IntEnum):
    """EtherCAT states as coded in AL control / AL status bits 3..0 (IDX guide table 4-18)."""

    INIT = 0x01
    PREOP = 0x02
    BOOT = 0x03
    SAFEOP = 0x04
    OP = 0x08


#: Legal transitions (IDX guide table 4-17); anything else is refused with 0x0011.
AL_TRANSITIONS: frozenset[tuple[AlState, AlState]] = frozenset({
    (AlState.INIT, AlState.PREOP), (AlState.INIT, AlState.BOOT),
    (AlState.PREOP, AlState.INIT), (AlState.PREOP, AlState.SAFEOP),
    (AlState.SAFEOP, AlState.PREOP), (AlState.SAFEOP, AlState.OP), (AlState.SAFEOP, AlState.INIT),
    (AlState.OP, AlState.SAFEOP), (AlState.OP, AlState.PREOP), (AlState.OP, AlState.INIT),
    (AlState.BOOT, AlState.INIT),
})


@dataclass(frozen=True, slots=True)
class SmConfig:
    """A SyncManager as the master configured it (registers 0x0800 + 8n)."""

    index: int
    start: int
    length: int
    control: int
    activate: int

    @property
    def enabled(self) -> bool:
        """Activated by the master (0x0806 bit 0) with a buffer of at least one byte."""
        return bool(self.activate & SM_ACT_ENABLE) and self.length > 0

    @property
    def mailbox(self) -> bool:
        """1-buffer (mailbox) mode, 0x0804 bits 1..0 = 10: a full buffer refuses the next write."""
        return (self.control & 0x03) == SM_CTRL_MAILBOX

    @property
    def ecat_writes(self) -> bool:
        """The master writes this buffer (0x0804 bit 2), the PDI reads it: outputs, mailbox out."""
        return bool(self.control & SM_CTRL_ECAT_WRITE)

    @property
    def on_output_register(self) -> bool:
        """A buffered (3-buffer) SyncManager the master writes whose buffer lies inside the Digital I/O
        Output Data register 0x0F00:0x0F03 (ET1100 data sheet II): an output terminal without a
        microcontroller (EL2008) drives its pins from there, so the ESC runs it as one in process RAM."""
        return (self.start >= REG_DIGITAL_OUT and self.start + self.length <= REG_DIGITAL_OUT_END
                and (self.control & 0x03) == 0 and bool(self.control & SM_CTRL_ECAT_WRITE))


@dataclass(slots=True)
class EscStats:
    """Counters a test or a user can read (frames seen by this ESC and what it refused)."""

    datagrams: int = 0
    #: Datagrams whose processing raised (Segment isolates them: the frame's other datagrams still run).
    datagram_errors: int = 0
    refused_accesses: int = 0
    #: SyncManagers the master enabled that the ESC did not activate (buffer in the register area, or
    #: overlapping a lower SyncManager), counted on every configuration write that leaves one so.
    refused_sms: int = 0
    al_refusals: int = 0
    watchdog_expiries: int = 0
    sii_commands: int = 0
