"""The SDO abort codes of CiA 301, the maxon IDX table 6-20 and ETG.1000.6 CoE, and one exception.

Every failure an SDO client (CANopen, CoE, the IDX's USB gateway) can see is an :class:`SdoAbort`
whose ``.code`` is the u32 abort code that goes on the wire. Each code is one member of
:class:`SdoAbortCode` carrying its CiA 301 / ETG text and, when the IDX guide lists it, the
table 6-20 Name and Cause word for word.
"""

from __future__ import annotations

from enum import IntEnum

from gatewaylab.common.errors import RemoteError

__all__ = ["SdoAbort", "SdoAbortCode", "abort_text"]


class SdoAbortCode(IntEnum):
    """One SDO abort code: its CiA 301 / ETG.1000.6 text and the IDX table 6-20 Name and Cause."""

    text: str
    idx_name: str | None
    idx_cause: str | None

    def __new__(cls, code: int, text: str, idx_name: str | None = None,
                idx_cause: str | None = None) -> SdoAbortCode:
        obj = int.__new__(cls, code)
        obj._value_ = code
        obj.text = text
        obj.idx_name = idx_name
        obj.idx_cause = idx_cause
        return obj

    NO_ABORT = (0x00000000, "No abort", "No abort", "Communication successful")
    TOGGLE_BIT_NOT_ALTERNATED = (0x05030000, "Toggle bit not alternated", "Toggle error",
                                 "Toggle bit not alternated")
    SDO_PROTOCOL_TIMED_OUT = (0x05040000, "SDO protocol timed out", "SDO timeout", "SDO protocol timed out")
    COMMAND_SPECIFIER_UNKNOWN = (0x05040001, "Command specifier unknown", "Command unknown",
                                 "Command specifier unknown")
    INVALID_BLOCK_SIZE = (0x05040002, "Invalid block size")
    INVALID_SEQUENCE_NUMBER = (0x05040003, "Invalid sequence number")
    CRC_ERROR = (0x05040004, "CRC error", "CRC error", "CRC check failed")
    OUT_OF_MEMORY = (0x05040005, "Out of memory")
    UNSUPPORTED_ACCESS = (0x06010000, "Unsupported access to an object", "Access error",
                          "Unsupported access to an object")
    WRITE_ONLY = (0x06010001, "Attempt to read a write only object", "Write only error",
                  "Read command to a write only object")
    READ_ONLY = (0x06010002, "Attempt to write a read only object", "Read only error",
                 "Write command to a read only object")
    SUBINDEX_CANNOT_BE_WRITTEN = (0x06010003, "Sub-index cannot be written, sub-index 0 must be 0",
                                  "Subindex cannot be written",
                                  'Subindex cannot be written, subindex 0 must be "0" (zero) for write access')
    COMPLETE_ACCESS_NOT_SUPPORTED = (0x06010004, "Complete access not supported")
    OBJECT_TOO_LONG = (0x06010005, "Object length exceeds mailbox size")
    MAPPED_TO_RXPDO = (0x06010006, "Object mapped to RxPDO, SDO download blocked")
    OBJECT_DOES_NOT_EXIST = (0x06020000, "Object does not exist in the object dictionary",
                             "Object does not exist error",
                             "Last read or write command had wrong object index or subindex")
    OBJECT_NOT_MAPPABLE = (0x06040041, "Object cannot be mapped to the PDO", "PDO mapping error",
                           "Object is not mappable to the PDO")
    PDO_LENGTH_EXCEEDED = (0x06040042, "Number and length of objects to be mapped would exceed PDO length",
                           "PDO length error", "Number and length of objects to be mapped would exceed PDO length")
    GENERAL_PARAMETER_INCOMPATIBILITY = (0x06040043, "General parameter incompatibility",
                                         "General parameter error", "General parameter incompatibility")
    GENERAL_INTERNAL_INCOMPATIBILITY = (0x06040047, "General internal incompatibility in the device",
                                        "General internal incompatibility error",
                                        "General internal incompatibility in device")
    HARDWARE_ERROR = (0x06060000, "Access failed due to a hardware error", "Hardware error",
                      "Access failed due to hardware error")
    LENGTH_MISMATCH = (0x06070010, "Data type does not match, length of service parameter does not match",
                       "Service parameter error",
                       "Data type does not match, length or service parameter do not match")
    LENGTH_TOO_HIGH = (0x06070012, "Data type does not match, length of service parameter too high")
    LENGTH_TOO_LOW = (0x06070013, "Data type does not match, length of service parameter too low",
                      "Service parameter too short error",
                      "Data type does not match, length of service parameter too low")
    SUBINDEX_DOES_NOT_EXIST = (0x06090011, "Sub-index does not exist", "Subindex error",
                               "Last read or write command had wrong object subindex")
    VALUE_RANGE_EXCEEDED = (0x06090030, "Value range of parameter exceeded", "Value range error",
                            "Value range of parameter exceeded")
    VALUE_TOO_HIGH = (0x06090031, "Value of parameter written too high")
    VALUE_TOO_LOW = (0x06090032, "Value of parameter written too low")
    MAX_LESS_THAN_MIN = (0x06090036, "Maximum value is less than minimum value")
    RESOURCE_NOT_AVAILABLE = (0x060A0023, "Resource not available: SDO connection")
    GENERAL_ERROR = (0x08000000, "General error", "General error", "General error")
    DATA_CANNOT_BE_STORED = (0x08000020, "Data cannot be transferred or stored to the application",
                             "Transfer or store error", "Data cannot be transferred or stored")
    DATA_CANNOT_BE_STORED_LOCAL_CONTROL = (
        0x08000021, "Data cannot be transferred or stored to the application because of local control")
    DATA_CANNOT_BE_STORED_DEVICE_STATE = (
        0x08000022, "Data cannot be transferred or stored because of the device state",
        "Wrong device state error",
        "Data cannot be transferred or stored to application because of present device state")
    NO_OBJECT_DICTIONARY = (0x08000023, "Object dictionary dynamic generation fails or no object dictionary")
    NO_DATA_AVAILABLE = (0x08000024, "No data available")
    PASSWORD_ERROR = (0x0F00FFBE, "Password is incorrect", "Password error", "Password is incorrect")
    ILLEGAL_COMMAND = (0x0F00FFBF, "Command code is illegal", "Illegal command error",
                       "Command code is illegal (does not exist)")
    WRONG_NMT_STATE = (0x0F00FFC0, "Device is in wrong NMT state", "Wrong NMT state error",
                       "Device is in wrong NMT state")

    @classmethod
    def known(cls, code: int) -> bool:
        """True when ``code`` is one of the codes above (a fuzzer's check that only spec codes go out)."""
        return code in cls._value2member_map_


def abort_text(code: int) -> str:
    """The CiA 301 / ETG text of a code, or "unknown abort code"."""
    member = SdoAbortCode._value2member_map_.get(code)
    return member.text if isinstance(member, SdoAbortCode) else "unknown abort code"


class SdoAbort(RemoteError):
    """An SDO transfer ended with abort code ``code`` (u32); raised by devices, sent by servers,
    received by clients: the one SDO error of CANopen, CoE and the IDX gateway."""

    code: int

    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(f"SDO abort 0x{code:08X} ({abort_text(code)}){': ' + message if message else ''}", code)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SdoAbort) and other.code == self.code

    def __hash__(self) -> int:
        return hash(("SdoAbort", self.code))

    def __reduce__(self) -> tuple[type[SdoAbort], tuple[int]]:
        return (SdoAbort, (self.code,))
