"""Byte layouts of the esd CAN-EtherCAT process image (manual 5.1.5.1-5.1.5.4, Figure 24).

Pure ``struct`` codecs, little-endian, used by the gateway and by master-side code alike:

* outputs (0x7000 / 0x7001): u16 Tx Counter Application, u16 Rx Counter Application,
  u16 Number of Tx Messages, then the Tx messages;
* inputs (0x6000 / 0x6001): u16 Tx Counter Gateway, u16 Rx Counter Gateway, u16 Number of Rx
  Messages, u16 Tx Transaction Number, then the Rx messages;
* 11-bit Rx message (10 B, 5.1.5.1): u16 {bits 0-3 length, bit 4 RTR, bits 5-15 identifier},
  8 data bytes; 11-bit Tx message (12 B, 5.1.5.3): u16 transaction number + the Rx layout;
* 29-bit Rx message (14 B, 5.1.5.2): u16 length (bits 0-3), u32 {bits 0-28 identifier, bit 30
  RTR, bit 31 29-bit frame} (the manual counts these bits 16-44/46/47 from the message start),
  8 data bytes; 29-bit Tx message (16 B, 5.1.5.4): u16 transaction number + the Rx layout.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import RemoteError

__all__ = [
    "FLAG_29BIT",
    "FLAG_RTR29",
    "ID29_MASK",
    "IN_HEADER",
    "OUT_HEADER",
    "RX11",
    "RX29",
    "RX_SIZE",
    "STATUS_PDO",
    "TX11",
    "TX29",
    "TX_SIZE",
    "CanStatus",
    "MessageError",
    "TxMessage",
    "decode_rx11",
    "decode_rx29",
    "decode_status_pdo",
    "decode_tx11",
    "decode_tx29",
    "encode_rx11",
    "encode_rx29",
    "encode_tx11",
    "encode_tx29",
    "input_size",
    "output_size",
]


OUT_HEADER = struct.Struct("<HHH")     # Tx counter, Rx counter, number of Tx messages
IN_HEADER = struct.Struct("<HHHH")     # Tx counter, Rx counter, number of Rx messages, Tx transaction no.
RX11 = struct.Struct("<H8s")
TX11 = struct.Struct("<HH8s")
RX29 = struct.Struct("<HI8s")
TX29 = struct.Struct("<HHI8s")
#: 0x1A85 'CAN Status PDO' (5.1.3.9): 48 bits = F108:01,02,03, 1 bit padding, F108:05,06, 10 bits
#: padding, F108:11..14, 12 bits padding, F108:21 (REC), F108:22 (TEC).
STATUS_PDO = struct.Struct("<BBBBBB")

#: Sizes in bytes of one message: (Tx in the outputs, Rx in the inputs) per identifier mode.
TX_SIZE = {False: TX11.size, True: TX29.size}
RX_SIZE = {False: RX11.size, True: RX29.size}
FLAG_29BIT = 0x80000000
FLAG_RTR29 = 0x40000000
ID29_MASK = 0x1FFFFFFF


@dataclass(frozen=True, slots=True)
class CanStatus:
    """0xF108 'CAN Status' (5.1.5.8) as a master reads it, by SDO or from the 0x1A85 PDO."""

    bus_off: bool = False           # :01, from the controller status
    warning_limit: bool = False     # :02 'Warning Limit reached'
    rx_overflow: bool = False       # :03 'Rx overflow'
    rx_errors: int = 0              # :21 Rx error counter
    tx_errors: int = 0              # :22 Tx error counter


def decode_status_pdo(buf: bytes | bytearray | memoryview, offset: int) -> CanStatus:
    """The 6 bytes of the 0x1A85 status PDO at ``offset`` (5.1.3.9): byte 0 bit 0 bus off, bit 1
    warning limit, bit 2 Rx overflow; byte 4 Rx error counter, byte 5 Tx error counter."""
    flags, _b1, _b2, _b3, rec, tec = STATUS_PDO.unpack_from(buf, offset)
    return CanStatus(bool(flags & 1), bool(flags & 2), bool(flags & 4), rec, tec)


class MessageError(RemoteError):
    """A Tx message the master wrote that no CAN frame can carry (identifier out of range)."""


@dataclass(frozen=True, slots=True)
class TxMessage:
    """One Tx message of the outputs: its transaction number and the frame it asks for."""

    transaction: int
    frame: CanFrame


def output_size(extended: bool, tx_messages: int) -> int:
    """Bytes of the outputs (5.1.3.7): 6 + messages x 12 (11-bit) or x 16 (29-bit)."""
    return OUT_HEADER.size + tx_messages * TX_SIZE[extended]


def input_size(extended: bool, rx_messages: int) -> int:
    """Bytes of the inputs (5.1.3.8): 8 + messages x 10 (11-bit) or x 14 (29-bit)."""
    return IN_HEADER.size + rx_messages * RX_SIZE[extended]


def _frame(can_id: int, extended: bool, rtr: bool, length: int, data: bytes) -> CanFrame:
    n = min(length, 8)  # a classic DLC of 9..15 means 8 bytes
    if rtr:
        return CanFrame(can_id, b"", extended=extended, rtr=True, dlc=n)
    return CanFrame(can_id, data[:n], extended=extended)


def decode_tx11(buf: bytes | bytearray | memoryview, offset: int) -> TxMessage:
    """The 11-bit Tx message at ``offset`` (5.1.5.3: bits 0-15 transaction number, 16-19 length,
    20 RTR, 21-31 identifier, 32-95 data)."""
    tn, word, data = TX11.unpack_from(buf, offset)
    return TxMessage(tn, _frame(word >> 5, False, bool(word & 0x10), word & 0x0F, data))


def decode_tx29(buf: bytes | bytearray | memoryview, offset: int) -> TxMessage:
    """The 29-bit Tx message at ``offset`` (5.1.5.4: bits 0-15 transaction number, 16-31 length,
    32-60 identifier, 62 RTR, 63 29-bit flag, 64-127 data). An 11-bit frame (bit 63 clear) with an
    identifier above 0x7FF raises :class:`MessageError`."""
    tn, length, word, data = TX29.unpack_from(buf, offset)
    extended = bool(word & FLAG_29BIT)
    can_id = word & ID29_MASK
    if not extended and can_id > 0x7FF:
        raise MessageError(f"11-bit message with identifier 0x{can_id:X}")
    return TxMessage(tn, _frame(can_id, extended, bool(word & FLAG_RTR29), length & 0x0F, data))


def _dlc(frame: CanFrame) -> int:
    return frame.dlc if frame.rtr else len(frame.data)


def encode_rx11(frame: CanFrame) -> bytes:
    """An 11-bit Rx message (5.1.5.1: bits 0-3 length, bit 4 RTR, bits 5-15 identifier, data)."""
    word = (frame.can_id & 0x7FF) << 5 | (0x10 if frame.rtr else 0) | (_dlc(frame) & 0x0F)
    return RX11.pack(word, b"" if frame.rtr else frame.data)


def encode_rx29(frame: CanFrame) -> bytes:
    """A 29-bit-queue Rx message (5.1.5.2: length, identifier, bit 46 RTR, bit 47 29-bit, data);
    standard frames travel in it too, with the 29-bit flag clear."""
    word = (frame.can_id & ID29_MASK) | (FLAG_29BIT if frame.extended else 0) | (FLAG_RTR29 if frame.rtr else 0)
    return RX29.pack(_dlc(frame), word, b"" if frame.rtr else frame.data)


# -- the master's side (tests, benchmarks, host libraries) ------------------------------------------------
def encode_tx11(transaction: int, frame: CanFrame) -> bytes:
    """An 11-bit Tx message as a master writes it (5.1.5.3)."""
    word = (frame.can_id & 0x7FF) << 5 | (0x10 if frame.rtr else 0) | (_dlc(frame) & 0x0F)
    return TX11.pack(transaction & 0xFFFF, word, b"" if frame.rtr else frame.data)


def encode_tx29(transaction: int, frame: CanFrame) -> bytes:
    """A 29-bit Tx message as a master writes it (5.1.5.4)."""
    word = (frame.can_id & ID29_MASK) | (FLAG_29BIT if frame.extended else 0) | (FLAG_RTR29 if frame.rtr else 0)
    return TX29.pack(transaction & 0xFFFF, _dlc(frame), word, b"" if frame.rtr else frame.data)


def decode_rx11(buf: bytes | bytearray | memoryview, offset: int) -> CanFrame:
    """An 11-bit Rx message as a master reads it (5.1.5.1)."""
    word, data = RX11.unpack_from(buf, offset)
    return _frame(word >> 5, False, bool(word & 0x10), word & 0x0F, data)


def decode_rx29(buf: bytes | bytearray | memoryview, offset: int) -> CanFrame:
    """A 29-bit-queue Rx message as a master reads it (5.1.5.2). An 11-bit frame (bit 47 clear) with
    an identifier above 0x7FF raises :class:`MessageError`."""
    length, word, data = RX29.unpack_from(buf, offset)
    extended = bool(word & FLAG_29BIT)
    can_id = word & ID29_MASK
    if not extended and can_id > 0x7FF:
        raise MessageError(f"11-bit message with identifier 0x{can_id:X}")
    return _frame(can_id, extended, bool(word & FLAG_RTR29), length & 0x0F, data)
