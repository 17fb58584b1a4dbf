"""EtherCAT errors, each carrying its wire code (AL status code, SDO abort code, FoE error code).

CoE SDO aborts are the object dictionary's one :class:`SdoAbort` / :class:`SdoAbortCode`
(re-exported here for the EtherCAT modules and their users).
"""

from __future__ import annotations

import enum

from gatewaylab.common.errors import ConfigError, LocalError, ProtocolError, RemoteError
from gatewaylab.od.aborts import SdoAbort as SdoAbort
from gatewaylab.od.aborts import SdoAbortCode as SdoAbortCode

__all__ = [
    "AlStatusCode", "AlStatusError", "EtherCATConfigError", "FoeBusy", "FoeError", "FoeErrorCode", "FrameFormatError",
    "MailboxError", "MailboxErrorCode", "MasterError", "PcapFormatError", "SlavePositionError", "WorkingCounterError",
]


class AlStatusCode(enum.IntEnum):
    """AL status codes (register 0x0134), ETG.1000.6 table 'AL Status Codes'."""

    NO_ERROR = 0x0000
    UNSPECIFIED = 0x0001
    NO_MEMORY = 0x0002
    INVALID_DEVICE_SETUP = 0x0003
    INVALID_STATE_CHANGE = 0x0011
    UNKNOWN_STATE = 0x0012
    BOOTSTRAP_NOT_SUPPORTED = 0x0013
    NO_VALID_FIRMWARE = 0x0014
    INVALID_MAILBOX_CONFIG_BOOT = 0x0015
    INVALID_MAILBOX_CONFIG = 0x0016
    INVALID_SM_CONFIG = 0x0017
    NO_VALID_INPUTS = 0x0018
    NO_VALID_OUTPUTS = 0x0019
    SYNCHRONIZATION_ERROR = 0x001A
    SM_WATCHDOG = 0x001B
    INVALID_SM_TYPES = 0x001C
    INVALID_OUTPUT_CONFIG = 0x001D
    INVALID_INPUT_CONFIG = 0x001E
    INVALID_WATCHDOG_CONFIG = 0x001F
    NEEDS_COLD_START = 0x0020
    NEEDS_INIT = 0x0021
    NEEDS_PREOP = 0x0022
    NEEDS_SAFEOP = 0x0023
    INVALID_INPUT_MAPPING = 0x0024
    INVALID_OUTPUT_MAPPING = 0x0025
    INCONSISTENT_SETTINGS = 0x0026
    FREERUN_NOT_SUPPORTED = 0x0027
    SYNCMODE_NOT_SUPPORTED = 0x0028
    INVALID_DC_SYNC_CONFIG = 0x0030
    INVALID_DC_CYCLE_TIME = 0x0035
    MBX_COE = 0x0043
    MBX_FOE = 0x0044
    EEPROM_NO_ACCESS = 0x0050
    EEPROM_ERROR = 0x0051


class FoeErrorCode(enum.IntEnum):
    """FoE error codes (ETG.1000.6 'FoE Error')."""

    NOT_DEFINED = 0x8000
    NOT_FOUND = 0x8001
    ACCESS_DENIED = 0x8002
    DISK_FULL = 0x8003
    ILLEGAL = 0x8004
    PACKET_NUMBER_WRONG = 0x8005
    ALREADY_EXISTS = 0x8006
    NO_USER = 0x8007
    BOOTSTRAP_ONLY = 0x8008
    NOT_BOOTSTRAP = 0x8009
    NO_RIGHTS = 0x800A
    PROGRAM_ERROR = 0x800B


class MailboxErrorCode(enum.IntEnum):
    """Mailbox error reply details (mailbox type 0, ETG.1000.4)."""

    SYNTAX = 0x0001
    UNSUPPORTED_PROTOCOL = 0x0002
    INVALID_CHANNEL = 0x0003
    SERVICE_NOT_SUPPORTED = 0x0004
    INVALID_HEADER = 0x0005
    SIZE_TOO_SHORT = 0x0006
    NO_MORE_MEMORY = 0x0007
    INVALID_SIZE = 0x0008


class FrameFormatError(ProtocolError):
    """A frame or datagram that cannot be parsed; the ESC drops it and counts it."""


class AlStatusError(RemoteError):
    """A state transition refused with an AL status code (register 0x0134)."""


class FoeError(RemoteError):
    """An FoE transfer ended by an FoE error packet."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(f"{message} (FoE error 0x{code:04X})", code)


class FoeBusy(RemoteError):
    """Raised by an FoE handler that needs time (flashing): the slave answers BUSY(done, entire)
    and the master repeats its last DATA packet later."""

    def __init__(self, done: int = 0, entire: int = 100) -> None:
        super().__init__(f"busy {done}/{entire}")
        self.done = done
        self.entire = entire


class MailboxError(RemoteError):
    """A mailbox message the slave answered with a mailbox error reply."""


class EtherCATConfigError(ConfigError):
    """A device description or rig section that cannot describe a real slave."""


class SlavePositionError(LocalError, IndexError):
    """A slave position the segment does not have (fault injection: unplug a slave)."""


class PcapFormatError(LocalError, ValueError):
    """Bytes that are not a pcap of :class:`~gatewaylab.ethercat.wire_pcap.PcapWriter`'s format."""


class MasterError(LocalError):
    """The in-process master was asked for something impossible (no such slave, not scanned...)."""


class WorkingCounterError(RemoteError):
    """A datagram came back with an unexpected working counter."""
