"""The maxon communication error codes (IDX Communication Guide chapter 6, table 6-20).

Every USB reply carries one of these DWORDs: they are SDO abort codes, members of the one
:class:`~gatewaylab.od.SdoAbortCode` enum (which also holds table 6-20's Name and Cause word for
word). Errors raised inside the device are :class:`IdxRemoteError`, an :class:`SdoAbort` whose
default text is the table's Name; the protocol turns them into the reply's error field at one
boundary.
"""

from __future__ import annotations

from gatewaylab.od.aborts import SdoAbort, SdoAbortCode, abort_text

__all__ = ["IdxRemoteError", "SdoAbortCode", "error_cause", "error_name", "idx_codes"]


def idx_codes() -> list[SdoAbortCode]:
    """The 25 codes of table 6-20, in code order."""
    return [code for code in SdoAbortCode if code.idx_name is not None]


def error_name(code: int) -> str:
    """The table 6-20 Name of a code exactly as the guide prints it (e.g. "SDO timeout"); for a
    code outside the table (another node's abort passed through the gateway) its CiA 301 text,
    else "error 0x........"."""
    member = SdoAbortCode._value2member_map_.get(code)
    if isinstance(member, SdoAbortCode):
        return member.idx_name if member.idx_name is not None else abort_text(code)
    return f"error 0x{code:08X}"


def error_cause(code: int) -> str:
    """The table 6-20 Cause of a code, "" for codes outside the table."""
    member = SdoAbortCode._value2member_map_.get(code)
    if isinstance(member, SdoAbortCode) and member.idx_cause is not None:
        return member.idx_cause
    return ""


class IdxRemoteError(SdoAbort):
    """A request the IDX refuses; ``code`` is what goes into the reply's error DWORD."""

    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(code, message)
        self.args = (message or f"{error_name(code)} (0x{code:08X})",)
        self.code: int = code

    def __str__(self) -> str:
        return str(self.args[0])

    def __reduce__(self) -> tuple[type[IdxRemoteError], tuple[int, str]]:  # type: ignore[override]
        return (IdxRemoteError, (self.code, str(self.args[0])))
