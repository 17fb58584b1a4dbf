"""The maxon communication error codes (IDX Communication Guide chapter 6, table 6-20).

Every USB reply carries one of these DWORDs. Errors raised inside the device carry the code in
``.code``; the protocol turns them into the reply's error field at one boundary.
"""

from __future__ import annotations

from enum import IntEnum

from ...canopen.errors import ABORT_NAMES
from ...common.errors import RemoteError


class ErrorCode(IntEnum):
    """Table 6-20 "Communication errors" (CiA 301 abort codes plus maxon-specific ones)."""

    NO_ABORT = 0x00000000
    TOGGLE_ERROR = 0x05030000
    SDO_TIMEOUT = 0x05040000
    COMMAND_UNKNOWN = 0x05040001
    CRC_ERROR = 0x05040004
    ACCESS_ERROR = 0x06010000
    WRITE_ONLY_ERROR = 0x06010001
    READ_ONLY_ERROR = 0x06010002
    SUBINDEX_CANNOT_BE_WRITTEN = 0x06010003
    OBJECT_DOES_NOT_EXIST = 0x06020000
    PDO_MAPPING_ERROR = 0x06040041
    PDO_LENGTH_ERROR = 0x06040042
    GENERAL_PARAMETER_ERROR = 0x06040043
    GENERAL_INTERNAL_INCOMPATIBILITY = 0x06040047
    HARDWARE_ERROR = 0x06060000
    SERVICE_PARAMETER_ERROR = 0x06070010
    SERVICE_PARAMETER_TOO_SHORT = 0x06070013
    SUBINDEX_ERROR = 0x06090011
    VALUE_RANGE_ERROR = 0x06090030
    GENERAL_ERROR = 0x08000000
    TRANSFER_OR_STORE_ERROR = 0x08000020
    WRONG_DEVICE_STATE = 0x08000022
    PASSWORD_ERROR = 0x0F00FFBE
    ILLEGAL_COMMAND = 0x0F00FFBF
    WRONG_NMT_STATE = 0x0F00FFC0


#: Table 6-20 word for word: code -> (Name, Cause).
_TABLE_6_20: dict[int, tuple[str, str]] = {
    ErrorCode.NO_ABORT: ("No abort", "Communication successful"),
    ErrorCode.TOGGLE_ERROR: ("Toggle error", "Toggle bit not alternated"),
    ErrorCode.SDO_TIMEOUT: ("SDO timeout", "SDO protocol timed out"),
    ErrorCode.COMMAND_UNKNOWN: ("Command unknown", "Command specifier unknown"),
    ErrorCode.CRC_ERROR: ("CRC error", "CRC check failed"),
    ErrorCode.ACCESS_ERROR: ("Access error", "Unsupported access to an object"),
    ErrorCode.WRITE_ONLY_ERROR: ("Write only error", "Read command to a write only object"),
    ErrorCode.READ_ONLY_ERROR: ("Read only error", "Write command to a read only object"),
    ErrorCode.SUBINDEX_CANNOT_BE_WRITTEN: (
        "Subindex cannot be written",
        'Subindex cannot be written, subindex 0 must be "0" (zero) for write access'),
    ErrorCode.OBJECT_DOES_NOT_EXIST: (
        "Object does not exist error", "Last read or write command had wrong object index or subindex"),
    ErrorCode.PDO_MAPPING_ERROR: ("PDO mapping error", "Object is not mappable to the PDO"),
    ErrorCode.PDO_LENGTH_ERROR: (
        "PDO length error", "Number and length of objects to be mapped would exceed PDO length"),
    ErrorCode.GENERAL_PARAMETER_ERROR: ("General parameter error", "General parameter incompatibility"),
    ErrorCode.GENERAL_INTERNAL_INCOMPATIBILITY: (
        "General internal incompatibility error", "General internal incompatibility in device"),
    ErrorCode.HARDWARE_ERROR: ("Hardware error", "Access failed due to hardware error"),
    ErrorCode.SERVICE_PARAMETER_ERROR: (
        "Service parameter error", "Data type does not match, length or service parameter do not match"),
    ErrorCode.SERVICE_PARAMETER_TOO_SHORT: (
        "Service parameter too short error", "Data type does not match, length of service parameter too low"),
    ErrorCode.SUBINDEX_ERROR: ("Subindex error", "Last read or write command had wrong object subindex"),
    ErrorCode.VALUE_RANGE_ERROR: ("Value range error", "Value range of parameter exceeded"),
    ErrorCode.GENERAL_ERROR: ("General error", "General error"),
    ErrorCode.TRANSFER_OR_STORE_ERROR: ("Transfer or store error", "Data cannot be transferred or stored"),
    ErrorCode.WRONG_DEVICE_STATE: (
        "Wrong device state error",
        "Data cannot be transferred or stored to application because of present device state"),
    ErrorCode.PASSWORD_ERROR: ("Password error", "Password is incorrect"),
    ErrorCode.ILLEGAL_COMMAND: ("Illegal command error", "Command code is illegal (does not exist)"),
    ErrorCode.WRONG_NMT_STATE: ("Wrong NMT state error", "Device is in wrong NMT state"),
}


def error_name(code: int) -> str:
    """The table 6-20 Name of a code exactly as the guide prints it (e.g. "SDO timeout"); for a
    code outside the table (another node's abort passed through the gateway) its CiA 301 text,
    else "error 0x........"."""
    entry = _TABLE_6_20.get(code)
    if entry is not None:
        return entry[0]
    return ABORT_NAMES.get(code, f"error 0x{code:08X}")


def error_cause(code: int) -> str:
    """The table 6-20 Cause of a code, "" for codes outside the table."""
    entry = _TABLE_6_20.get(code)
    return entry[1] if entry is not None else ""


class IdxRemoteError(RemoteError):
    """A request the IDX refuses; ``code`` is what goes into the reply's error DWORD."""

    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(message or f"{error_name(code)} (0x{code:08X})", code)
        self.code: int = code
