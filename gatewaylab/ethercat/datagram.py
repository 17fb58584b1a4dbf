"""EtherCAT frame and datagram codecs (ETG.1000.4 framing), pure functions on bytes.

A frame on the wire is an Ethernet II header (EtherType 0x88A4), a 2-byte EtherCAT header
(length:11, reserved:1, type:4; type 1 = datagrams) and one or more datagrams, each
``cmd idx address(4) len/flags(2) irq(2) data wkc(2)``. The ESC processes frames in place
(``segment.py``); these codecs exist for the in-process master, golden tests and pcap tools.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Final

from gatewaylab.ethercat.errors import FrameFormatError

__all__ = [
    "ADP_ADO",
    "BROADCAST_MAC",
    "CIRCULATING",
    "DATAGRAM_HEADER",
    "DATAGRAM_OVERHEAD",
    "ECAT_HEADER",
    "ECAT_HEADER_LEN",
    "ECAT_TYPE_DATAGRAMS",
    "ETHERTYPE_ETHERCAT",
    "ETH_HEADER",
    "ETH_HEADER_LEN",
    "LEN_MASK",
    "MAX_DATAGRAM_DATA",
    "MIN_ETH_PAYLOAD",
    "MORE",
    "WKC",
    "Command",
    "Datagram",
    "Frame",
    "decode_datagrams",
    "decode_frame",
    "encode_datagrams",
    "encode_frame",
]


ETHERTYPE_ETHERCAT: Final = 0x88A4
ETH_HEADER: Final = struct.Struct("!6s6sH")
ECAT_HEADER: Final = struct.Struct("<H")
DATAGRAM_HEADER: Final = struct.Struct("<BBIHH")  # cmd, idx, address, len/flags, irq
WKC: Final = struct.Struct("<H")
ADP_ADO: Final = struct.Struct("<HH")

ETH_HEADER_LEN: Final = 14
ECAT_HEADER_LEN: Final = 2
DATAGRAM_OVERHEAD: Final = 12  # 10 header + 2 working counter
MAX_DATAGRAM_DATA: Final = 1486  # 1500 - 2 (EtherCAT header) - 12 (one datagram's overhead)
BROADCAST_MAC = b"\xff" * 6
ECAT_TYPE_DATAGRAMS: Final = 1
MIN_ETH_PAYLOAD: Final = 46  # frames shorter than 60 bytes are padded on the wire

LEN_MASK: Final = 0x07FF
CIRCULATING = 0x4000
MORE: Final = 0x8000


class Command(enum.IntEnum):
    """Datagram commands (ETG.1000.4 table 'EtherCAT command types')."""

    NOP = 0
    APRD = 1
    APWR = 2
    APRW = 3
    FPRD = 4
    FPWR = 5
    FPRW = 6
    BRD = 7
    BWR = 8
    BRW = 9
    LRD = 10
    LWR = 11
    LRW = 12
    ARMW = 13
    FRMW = 14


@dataclass(frozen=True, slots=True)
class Datagram:
    """One datagram; ``address`` is the 32-bit address field (ADP | ADO << 16 for physical)."""

    command: Command
    index: int
    address: int
    data: bytes
    wkc: int = 0
    irq: int = 0
    circulating: bool = False

    @property
    def adp(self) -> int:
        """The address position (ADP): a negative slave position (APxx) or a station address (FPxx), ETG.1000.4."""
        return self.address & 0xFFFF

    @property
    def ado(self) -> int:
        """The address offset (ADO): the ESC register or memory address a physical datagram accesses (ETG.1000.4)."""
        return (self.address >> 16) & 0xFFFF

    @staticmethod
    def physical(command: Command, index: int, adp: int, ado: int, data: bytes, wkc: int = 0) -> Datagram:
        """Build an auto-increment, configured or broadcast datagram from ADP and ADO rather than a packed address."""
        return Datagram(command, index, (adp & 0xFFFF) | ((ado & 0xFFFF) << 16), data, wkc)


@dataclass(frozen=True, slots=True)
class Frame:
    """An Ethernet frame carrying EtherCAT datagrams."""

    datagrams: tuple[Datagram, ...]
    dst: bytes = BROADCAST_MAC
    src: bytes = b"\x02\x00\x00\x00\x00\x01"


def encode_datagrams(datagrams: tuple[Datagram, ...] | list[Datagram]) -> bytes:
    """EtherCAT header + datagrams (the Ethernet payload)."""
    parts: list[bytes] = []
    total = 0
    n = len(datagrams)
    for i, d in enumerate(datagrams):
        if len(d.data) > MAX_DATAGRAM_DATA:
            raise FrameFormatError(f"datagram data of {len(d.data)} bytes does not fit a frame")
        flags = len(d.data) | (MORE if i < n - 1 else 0) | (CIRCULATING if d.circulating else 0)
        parts.append(DATAGRAM_HEADER.pack(int(d.command), d.index & 0xFF, d.address & 0xFFFFFFFF,
                                          flags, d.irq & 0xFFFF))
        parts.append(d.data)
        parts.append(WKC.pack(d.wkc & 0xFFFF))
        total += DATAGRAM_OVERHEAD + len(d.data)
    if total > 1498:
        raise FrameFormatError(f"datagrams of {total} bytes exceed one Ethernet frame")
    return ECAT_HEADER.pack(total | (ECAT_TYPE_DATAGRAMS << 12)) + b"".join(parts)


def encode_frame(frame: Frame) -> bytes:
    """A whole Ethernet frame, padded to the 60-byte minimum."""
    payload = encode_datagrams(frame.datagrams)
    if len(payload) < MIN_ETH_PAYLOAD:
        payload += bytes(MIN_ETH_PAYLOAD - len(payload))
    return ETH_HEADER.pack(frame.dst, frame.src, ETHERTYPE_ETHERCAT) + payload


def decode_datagrams(payload: bytes | bytearray | memoryview) -> tuple[Datagram, ...]:
    """Parse the EtherCAT header and datagrams; raises FrameFormatError on malformed input."""
    if len(payload) < ECAT_HEADER_LEN:
        raise FrameFormatError("no EtherCAT header")
    (hdr,) = ECAT_HEADER.unpack_from(payload, 0)
    length = hdr & LEN_MASK
    if hdr >> 12 != ECAT_TYPE_DATAGRAMS:
        raise FrameFormatError(f"EtherCAT frame type {hdr >> 12} is not 'datagrams'")
    if length + ECAT_HEADER_LEN > len(payload):
        raise FrameFormatError(f"EtherCAT length {length} exceeds the frame")
    out: list[Datagram] = []
    pos = ECAT_HEADER_LEN
    end = ECAT_HEADER_LEN + length
    while True:
        if pos + DATAGRAM_OVERHEAD > end:
            raise FrameFormatError("truncated datagram header")
        cmd, idx, address, flags, irq = DATAGRAM_HEADER.unpack_from(payload, pos)
        dlen = flags & LEN_MASK
        if pos + DATAGRAM_OVERHEAD + dlen > end:
            raise FrameFormatError("datagram data exceeds the EtherCAT length")
        try:
            command = Command(cmd)
        except ValueError:
            raise FrameFormatError(f"unknown datagram command {cmd}") from None
        data = bytes(payload[pos + 10:pos + 10 + dlen])
        (wkc,) = WKC.unpack_from(payload, pos + 10 + dlen)
        out.append(Datagram(command, idx, address, data, wkc, irq, bool(flags & CIRCULATING)))
        pos += DATAGRAM_OVERHEAD + dlen
        if not flags & MORE:
            break
    return tuple(out)


def decode_frame(raw: bytes | bytearray | memoryview) -> Frame:
    """Parse a whole Ethernet frame (EtherType 0x88A4 checked, then the datagrams); raises FrameFormatError."""
    if len(raw) < ETH_HEADER_LEN + ECAT_HEADER_LEN:
        raise FrameFormatError("frame shorter than the Ethernet + EtherCAT headers")
    dst, src, ethertype = ETH_HEADER.unpack_from(raw, 0)
    if ethertype != ETHERTYPE_ETHERCAT:
        raise FrameFormatError(f"EtherType 0x{ethertype:04X} is not EtherCAT")
    return Frame(decode_datagrams(memoryview(raw)[ETH_HEADER_LEN:]), dst, src)
