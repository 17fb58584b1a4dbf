"""The maxon communication error codes (IDX Communication Guide chapter 6, table 6-20).

Every USB reply carries one of these DWORDs. Errors raised inside the device carry the code in
``.code``; the protocol turns them into the reply's error field at one boundary.
"""

from __future__ import annotations

from enum import IntEnum

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


def error_name(code: int) -> str:
    """Human name of a code: the table 6-20 name, or the hex value for codes outside it."""
    try:
        return ErrorCode(code).name.replace("_", " ").lower()
    except ValueError:
        return f"error 0x{code:08X}"


class IdxRemoteError(RemoteError):
    """A request the IDX refuses; ``code`` is what goes into the reply's error DWORD."""

    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(message or f"{error_name(code)} (0x{code:08X})", code)
        self.code: int = code
