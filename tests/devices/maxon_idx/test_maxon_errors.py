"""Error code names (IDX guide chapter 6, table 6-20) as the host client and the CLI print them."""

from __future__ import annotations

from gatewaylab.devices.maxon_idx.errors import error_cause, error_name, idx_codes
from gatewaylab.hosts.maxon_idx.client import IdxError, IdxTimeout

#: Table 6-20 "Communication errors", Abort code / Name / Cause, copied from the guide.
TABLE_6_20 = [
    (0x00000000, "No abort", "Communication successful"),
    (0x05030000, "Toggle error", "Toggle bit not alternated"),
    (0x05040000, "SDO timeout", "SDO protocol timed out"),
    (0x05040001, "Command unknown", "Command specifier unknown"),
    (0x05040004, "CRC error", "CRC check failed"),
    (0x06010000, "Access error", "Unsupported access to an object"),
    (0x06010001, "Write only error", "Read command to a write only object"),
    (0x06010002, "Read only error", "Write command to a read only object"),
    (0x06010003, "Subindex cannot be written",
     'Subindex cannot be written, subindex 0 must be "0" (zero) for write access'),
    (0x06020000, "Object does not exist error", "Last read or write command had wrong object index or subindex"),
    (0x06040041, "PDO mapping error", "Object is not mappable to the PDO"),
    (0x06040042, "PDO length error", "Number and length of objects to be mapped would exceed PDO length"),
    (0x06040043, "General parameter error", "General parameter incompatibility"),
    (0x06040047, "General internal incompatibility error", "General internal incompatibility in device"),
    (0x06060000, "Hardware error", "Access failed due to hardware error"),
    (0x06070010, "Service parameter error", "Data type does not match, length or service parameter do not match"),
    (0x06070013, "Service parameter too short error", "Data type does not match, length of service parameter too low"),
    (0x06090011, "Subindex error", "Last read or write command had wrong object subindex"),
    (0x06090030, "Value range error", "Value range of parameter exceeded"),
    (0x08000000, "General error", "General error"),
    (0x08000020, "Transfer or store error", "Data cannot be transferred or stored"),
    (0x08000022, "Wrong device state error",
     "Data cannot be transferred or stored to application because of present device state"),
    (0x0F00FFBE, "Password error", "Password is incorrect"),
    (0x0F00FFBF, "Illegal command error", "Command code is illegal (does not exist)"),
    (0x0F00FFC0, "Wrong NMT state error", "Device is in wrong NMT state"),
]


def test_every_code_has_the_table_name_and_cause() -> None:
    """Chapter 6 table 6-20: 25 codes; each one's Name and Cause exactly as the guide prints them."""
    assert [int(c) for c in idx_codes()] == [code for code, _n, _c in TABLE_6_20]
    for code, name, cause in TABLE_6_20:
        assert (error_name(code), error_cause(code)) == (name, cause), hex(code)


def test_codes_outside_the_table_are_still_named() -> None:
    """Chapter 5: a node's own CiA 301 abort code is passed through; 0x06070012 is not in table 6-20
    but still gets a readable name, an unknown code its hex value."""
    assert "too high" in error_name(0x06070012) and error_cause(0x06070012) == ""
    assert error_name(0x12345678) == "error 0x12345678"


def test_client_exceptions_carry_code_name_and_cause() -> None:
    """Chapter 6: a missing node is 0x05040000 "SDO timeout"; the exception says what was asked."""
    exc = IdxError(0x05040000, "read node 9 0x1000:00")
    assert (exc.code, exc.name, exc.cause) == (0x05040000, "SDO timeout", "SDO protocol timed out")
    assert str(exc) == 'read node 9 0x1000:00: 0x05040000 "SDO timeout" (SDO protocol timed out)'
    silent = IdxTimeout("ReadObject", 0.2)
    assert silent.code == 0x05040000 and "no reply frame from the IDX within 0.2 s" in str(silent)
