"""CiA 305 LSS frames: command specifiers, states, the LSS address and the request/response codecs.

The IDX guide chapter 3.5 (table 3-14) lists the services; their frames follow CiA 305 V3.0:
every LSS frame is 8 bytes, the master sends on COB-ID 0x7E5, slaves answer on 0x7E4, byte 0 is
the command specifier (cs), numbers are little-endian, unused bytes are 0. What the slave
(:mod:`.slave`) and the master (:mod:`.master`) both speak lives here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum, IntEnum

from gatewaylab.common.errors import LocalError

__all__ = [
    "ACTIVATE_FRAME",
    "BIT_TIMING_TABLE",
    "FASTSCAN_CONFIRM",
    "FASTSCAN_FRAME",
    "LSS_MASTER_COB_ID",
    "LSS_SLAVE_COB_ID",
    "TWO_BYTE_FRAME",
    "U32_FRAME",
    "UNCONFIGURED",
    "Cs",
    "LssAddress",
    "LssState",
    "bit_timing_index",
    "encode_activate_bit_timing",
    "encode_configure_bit_timing",
    "encode_configure_node_id",
    "encode_cs",
    "encode_fastscan",
    "encode_result",
    "encode_switch_global",
    "encode_u32",
]


#: COB-ID of LSS master requests (IDX guide 3.5).
LSS_MASTER_COB_ID = 0x7E5
#: COB-ID of LSS slave responses (IDX guide 3.5).
LSS_SLAVE_COB_ID = 0x7E4
#: Node-ID value of a non-configured device (IDX guide 3.5).
UNCONFIGURED = 0xFF

#: CiA 305 standard bit timing table (table selector 0): index -> bit rate; None = reserved.
#: Index 9 (automatic bit rate detection) is not supported by the emulated controller.
BIT_TIMING_TABLE: tuple[int | None, ...] = (
    1_000_000, 800_000, 500_000, 250_000, 125_000, None, 50_000, 20_000, 10_000)

U32_FRAME = struct.Struct("<BI3x")         # cs + 32-bit value (identity, fastscan IDNumber part)
FASTSCAN_FRAME = struct.Struct("<BIBBB")    # cs, IDNumber, BitChecked, LSSSub, LSSNext
ACTIVATE_FRAME = struct.Struct("<BH5x")     # cs, switch delay (ms)
TWO_BYTE_FRAME = struct.Struct("<BBB5x")    # cs + two bytes (error code + specific, selector + index)


class Cs(IntEnum):
    """LSS command specifiers (IDX guide table 3-14, CiA 305 V3.0)."""

    SWITCH_STATE_GLOBAL = 0x04
    CONFIGURE_NODE_ID = 0x11
    CONFIGURE_BIT_TIMING = 0x13
    ACTIVATE_BIT_TIMING = 0x15
    STORE_CONFIGURATION = 0x17
    SWITCH_SELECTIVE_VENDOR = 0x40
    SWITCH_SELECTIVE_PRODUCT = 0x41
    SWITCH_SELECTIVE_REVISION = 0x42
    SWITCH_SELECTIVE_SERIAL = 0x43
    SWITCH_SELECTIVE_RESPONSE = 0x44
    IDENTIFY_VENDOR = 0x46
    IDENTIFY_PRODUCT = 0x47
    IDENTIFY_REVISION_LOW = 0x48
    IDENTIFY_REVISION_HIGH = 0x49
    IDENTIFY_SERIAL_LOW = 0x4A
    IDENTIFY_SERIAL_HIGH = 0x4B
    IDENTIFY_NON_CONFIGURED = 0x4C
    IDENTIFY_SLAVE = 0x4F
    IDENTIFY_NON_CONFIGURED_SLAVE = 0x50
    FASTSCAN = 0x51
    INQUIRE_VENDOR = 0x5A
    INQUIRE_PRODUCT = 0x5B
    INQUIRE_REVISION = 0x5C
    INQUIRE_SERIAL = 0x5D
    INQUIRE_NODE_ID = 0x5E


class LssState(Enum):
    """LSS slave states (CiA 305; IDX guide 3.5.1)."""

    WAITING = 0
    CONFIGURATION = 1


FASTSCAN_CONFIRM = 0x80  # BitChecked value that restarts a Fastscan (CiA 305 clause 8.3.5)


@dataclass(frozen=True, slots=True)
class LssAddress:
    """The 128-bit LSS address = identity object 0x1018 sub 1..4 (IDX guide 3.5)."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int

    def part(self, sub: int) -> int:
        """The 32-bit part ``sub`` (0 vendor, 1 product, 2 revision, 3 serial): the order of 0x1018 sub 1..4."""
        return (self.vendor_id, self.product_code, self.revision, self.serial)[sub]


# -- codecs -----------------------------------------------------------------------------------
def encode_switch_global(mode: LssState) -> bytes:
    """Switch state global request (CiA 305): 1 = configuration, 0 = waiting."""
    return TWO_BYTE_FRAME.pack(Cs.SWITCH_STATE_GLOBAL, mode.value, 0)


def encode_u32(cs: int, value: int) -> bytes:
    """A request or response carrying one 32-bit number (selective, identify, inquire)."""
    return U32_FRAME.pack(cs, value & 0xFFFFFFFF)


def encode_cs(cs: int) -> bytes:
    """A request with only a command specifier (inquire services, store, ...)."""
    return bytes((cs,)) + bytes(7)


def encode_configure_node_id(node_id: int) -> bytes:
    """Configure node-ID request (CiA 305; 0xFF = unconfigured)."""
    return TWO_BYTE_FRAME.pack(Cs.CONFIGURE_NODE_ID, node_id & 0xFF, 0)


def encode_configure_bit_timing(index: int, selector: int = 0) -> bytes:
    """Configure bit timing request: table selector 0, table index."""
    return TWO_BYTE_FRAME.pack(Cs.CONFIGURE_BIT_TIMING, selector & 0xFF, index & 0xFF)


def encode_activate_bit_timing(delay_ms: int) -> bytes:
    """Activate bit timing request with the switch delay in ms."""
    return ACTIVATE_FRAME.pack(Cs.ACTIVATE_BIT_TIMING, delay_ms & 0xFFFF)


def encode_result(cs: int, error: int, specific: int = 0) -> bytes:
    """Configure node-ID / bit timing / store responses: cs, error code, specific error."""
    return TWO_BYTE_FRAME.pack(cs, error, specific)


def encode_fastscan(id_number: int, bit_checked: int, lss_sub: int, lss_next: int) -> bytes:
    """One Fastscan request: id bits, bit checked, LSS sub, LSS next (CiA 305)."""
    return FASTSCAN_FRAME.pack(Cs.FASTSCAN, id_number & 0xFFFFFFFF, bit_checked, lss_sub, lss_next)


def bit_timing_index(bitrate: int) -> int:
    """CiA 305 table index of a bit rate; raises LocalError for rates outside the table."""
    try:
        return BIT_TIMING_TABLE.index(bitrate)
    except ValueError:
        raise LocalError(f"bit rate {bitrate} is not in the CiA 305 bit timing table") from None

