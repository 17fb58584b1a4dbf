"""Random EtherCAT frames for the storm tests (issue 15: 'A malformed EtherCAT frame kills the segment').

EtherType 0x88A4 with random bytes, and EtherCAT headers with 1-4 datagrams of random command,
address and length, some lengths lying (datagram length or EtherCAT length longer or shorter than
the bytes that follow). Used by the sans-I/O storm and by the sender in the wire storm (standalone).

``keep_eeprom``: a write-enabled SII write command (0x0502 bit 0 + command 2) reprograms the EEPROM
of a real ESC too, after which no master finds the original slave; the storms that must leave a
segment SOEM can re-initialise clear that bit and aim the FMMU configurations they shape at
process RAM and FMMU0-2 (the ones SOEM's config_init clears).
"""

from __future__ import annotations

import random
import struct

ETH = b"\xff" * 6 + b"\x02\x00\x00\x00\x00\x01" + b"\x88\xa4"
DG = struct.Struct("<BBIHH")
FMMU = struct.Struct("<IHBBHBBB3x")
#: Registers with behaviour (AL, SII, FMMU, SM, DC, watchdog) and the mailbox / process data areas.
HOT = (0x0000, 0x0010, 0x0012, 0x0100, 0x0120, 0x0130, 0x0300, 0x0400, 0x0420, 0x0500, 0x0502, 0x0504,
       0x0508, 0x0600, 0x0610, 0x0620, 0x0800, 0x0808, 0x0810, 0x0818, 0x0900, 0x0910, 0x0920, 0x0981,
       0x0990, 0x09A0, 0x0FF0, 0x1000, 0x1080, 0x1100, 0x1180, 0x2FF8, 0xFFF0)
WRITES = {2, 3, 5, 6, 8, 9, 13, 14}  # APWR APRW FPWR FPRW BWR BRW ARMW FRMW


def _datagram(rng: random.Random, last: bool, keep_eeprom: bool) -> bytes:
    cmd = rng.randrange(16) if rng.random() < 0.97 else rng.randrange(256)
    dlen = rng.choice((1, 2, 4, 8, 16, 32, 48, 128, rng.randrange(300), rng.randrange(1500)))
    if cmd in (10, 11, 12):  # logical
        address = rng.choice((0, 0x10000, 0xFFFFFFF0, rng.randrange(0x100), rng.randrange(1 << 32)))
        ado = -1
    else:
        ado = rng.choice(HOT) if rng.random() < 0.7 else rng.randrange(0x10000)
        adp = rng.choice((0, 0, 0xFFFF, 0xFFFE, 0x1001, 0x1002, 0x1003, rng.randrange(0x10000)))
        address = adp | ado << 16
    data = bytearray(rng.randbytes(dlen))
    if ado in (0x0600, 0x0610, 0x0620) and dlen >= 16 and rng.random() < 0.7:
        # a plausible FMMU: small logical start, bit-wise or byte-wise, near or past the end of RAM
        phys = rng.choice((0x1000, 0x1100, 0x2FFF, 0x3000, 0x0120, 0xFFFF, rng.randrange(0x10000)))
        if keep_eeprom:
            phys = rng.choice((0x1000, 0x1100, 0x2FFF, 0x3000, rng.randrange(0x1000, 0x10000)))
        FMMU.pack_into(data, 0, rng.choice((0, 1, 0x100, rng.randrange(1 << 32))),
                       rng.choice((1, 2, 8, 0x100, 0xFFFF)), rng.randrange(8), rng.randrange(8), phys,
                       rng.randrange(8), rng.randrange(1, 4), 1)
    if keep_eeprom and cmd in WRITES and ado >= 0 and ado <= 0x0502 < ado + dlen:
        data[0x0502 - ado] &= 0xFE  # no SII write enable
    lie = rng.random()
    if lie < 0.1:
        data = data[:rng.randrange(len(data) + 1)]  # shorter than announced
    elif lie < 0.15:
        data += rng.randbytes(rng.randrange(1, 40))  # longer than announced
    flags = (dlen & 0x7FF) | (0 if last else 0x8000) | (0x4000 if rng.random() < 0.05 else 0)
    return DG.pack(cmd & 0xFF, rng.randrange(256), address, flags, rng.randrange(0x10000)) + bytes(data) \
        + rng.randbytes(2)


def storm_frame(rng: random.Random, *, keep_eeprom: bool = False) -> bytes:
    """One random frame (at most 1514 bytes, as a NIC would carry)."""
    kind = rng.random()
    if kind < 0.1:
        return (ETH + rng.randbytes(rng.randrange(200)))[:1514]
    n = rng.randint(1, 4)
    body = b"".join(_datagram(rng, i == n - 1, keep_eeprom) for i in range(n))
    length = len(body) if rng.random() < 0.85 else rng.randrange(0x800)
    ftype = 1 if rng.random() < 0.95 else rng.randrange(16)
    return (ETH + struct.pack("<H", length & 0x7FF | ftype << 12) + body)[:1514]


def storm(seed: int, count: int, *, keep_eeprom: bool = False) -> list[bytes]:
    rng = random.Random(seed)
    return [storm_frame(rng, keep_eeprom=keep_eeprom) for _ in range(count)]
