"""SDO abort codes (CiA 301, IDX Communication Guide chapter 6, table 6-20) as one error class.

Every failure an SDO client can see is an :class:`SdoAbort` whose ``.code`` is the u32 abort
code that goes on the wire. Device code raises it; the SDO server turns it into an abort frame.
"""

from __future__ import annotations

from ..common.errors import RemoteError

NO_ABORT = 0x00000000
TOGGLE_BIT_NOT_ALTERNATED = 0x05030000
SDO_PROTOCOL_TIMED_OUT = 0x05040000
COMMAND_SPECIFIER_UNKNOWN = 0x05040001
INVALID_BLOCK_SIZE = 0x05040002          # CiA 301, block mode only
INVALID_SEQUENCE_NUMBER = 0x05040003     # CiA 301, block mode only
CRC_ERROR = 0x05040004
OUT_OF_MEMORY = 0x05040005               # CiA 301
UNSUPPORTED_ACCESS = 0x06010000
WRITE_ONLY = 0x06010001                  # "read command to a write only object"
READ_ONLY = 0x06010002                   # "write command to a read only object"
SUBINDEX_CANNOT_BE_WRITTEN = 0x06010003  # "sub-index 0 must be 0 for write access"
OBJECT_DOES_NOT_EXIST = 0x06020000
OBJECT_NOT_MAPPABLE = 0x06040041
PDO_LENGTH_EXCEEDED = 0x06040042
GENERAL_PARAMETER_INCOMPATIBILITY = 0x06040043
GENERAL_INTERNAL_INCOMPATIBILITY = 0x06040047
HARDWARE_ERROR = 0x06060000
LENGTH_MISMATCH = 0x06070010
LENGTH_TOO_HIGH = 0x06070012             # CiA 301 (not in the IDX table; the IDX uses 0x06070010)
LENGTH_TOO_LOW = 0x06070013
SUBINDEX_DOES_NOT_EXIST = 0x06090011
VALUE_RANGE_EXCEEDED = 0x06090030
VALUE_TOO_HIGH = 0x06090031              # CiA 301 (not in the IDX table)
VALUE_TOO_LOW = 0x06090032               # CiA 301 (not in the IDX table)
GENERAL_ERROR = 0x08000000
DATA_CANNOT_BE_STORED = 0x08000020
DATA_CANNOT_BE_STORED_DEVICE_STATE = 0x08000022
PASSWORD_ERROR = 0x0F00FFBE
ILLEGAL_COMMAND = 0x0F00FFBF
WRONG_NMT_STATE = 0x0F00FFC0

#: Names of the abort codes, for messages and reports.
ABORT_NAMES: dict[int, str] = {
    NO_ABORT: "No abort",
    TOGGLE_BIT_NOT_ALTERNATED: "Toggle bit not alternated",
    SDO_PROTOCOL_TIMED_OUT: "SDO protocol timed out",
    COMMAND_SPECIFIER_UNKNOWN: "Command specifier unknown",
    INVALID_BLOCK_SIZE: "Invalid block size",
    INVALID_SEQUENCE_NUMBER: "Invalid sequence number",
    CRC_ERROR: "CRC error",
    OUT_OF_MEMORY: "Out of memory",
    UNSUPPORTED_ACCESS: "Unsupported access to an object",
    WRITE_ONLY: "Attempt to read a write only object",
    READ_ONLY: "Attempt to write a read only object",
    SUBINDEX_CANNOT_BE_WRITTEN: "Sub-index cannot be written, sub-index 0 must be 0",
    OBJECT_DOES_NOT_EXIST: "Object does not exist in the object dictionary",
    OBJECT_NOT_MAPPABLE: "Object cannot be mapped to the PDO",
    PDO_LENGTH_EXCEEDED: "Number and length of objects to be mapped would exceed PDO length",
    GENERAL_PARAMETER_INCOMPATIBILITY: "General parameter incompatibility",
    GENERAL_INTERNAL_INCOMPATIBILITY: "General internal incompatibility in the device",
    HARDWARE_ERROR: "Access failed due to a hardware error",
    LENGTH_MISMATCH: "Data type does not match, length of service parameter does not match",
    LENGTH_TOO_HIGH: "Data type does not match, length of service parameter too high",
    LENGTH_TOO_LOW: "Data type does not match, length of service parameter too low",
    SUBINDEX_DOES_NOT_EXIST: "Sub-index does not exist",
    VALUE_RANGE_EXCEEDED: "Value range of parameter exceeded",
    VALUE_TOO_HIGH: "Value of parameter written too high",
    VALUE_TOO_LOW: "Value of parameter written too low",
    GENERAL_ERROR: "General error",
    DATA_CANNOT_BE_STORED: "Data cannot be transferred or stored to the application",
    DATA_CANNOT_BE_STORED_DEVICE_STATE: "Data cannot be transferred or stored because of the device state",
    PASSWORD_ERROR: "Password is incorrect",
    ILLEGAL_COMMAND: "Command code is illegal",
    WRONG_NMT_STATE: "Device is in wrong NMT state",
}


class SdoAbort(RemoteError):
    """An SDO transfer ended with abort code ``code`` (u32, CiA 301)."""

    code: int

    def __init__(self, code: int, message: str = "") -> None:
        name = ABORT_NAMES.get(code, "unknown abort code")
        super().__init__(f"SDO abort 0x{code:08X} ({name}){': ' + message if message else ''}", code)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SdoAbort) and other.code == self.code

    def __hash__(self) -> int:
        return hash(("SdoAbort", self.code))

    def __reduce__(self) -> tuple[type[SdoAbort], tuple[int]]:
        return (SdoAbort, (self.code,))
