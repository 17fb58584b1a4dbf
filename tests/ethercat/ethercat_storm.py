"""Random EtherCAT frames for the storm tests (issue 15: 'A malformed EtherCAT frame kills the segment').

EtherType 0x88A4 with random bytes, and EtherCAT headers with 1-4 datagrams of random command,
address and length, some lengths lying (datagram length or EtherCAT length longer or shorter than
the bytes that follow). Used by the sans-I/O storm and by the sender in the wire storm (standalone).

``keep_eeprom``: a write-enabled SII write command (0x0502 bit 0 + command 2) reprograms the EEPROM
of a real ESC too, after which no master finds the original slave; the storms that must leave a
segment SOEM can re-initialise clear that bit and aim the FMMU configurations they shape at
process RAM and FMMU0-2 (the ones SOEM's config_init clears). A writing FMMU over the EEPROM
interface registers is such a write too (an FMMU reaches the registers, ET1100 data sheet I, FMMU:
any physical address): a logical datagram through it writes 0x0502-0x050B like an FPWR, so every
FMMU a storm write touches is kept from writing there (:func:`no_sii_fmmu`).
"""

from __future__ import annotations

import random
import struct

ETH = b"\xff" * 6 + b"\x02\x00\x00\x00\x00\x01" + b"\x88\xa4"
DG = struct.Struct("<BBIHH")
FMMU = struct.Struct("<IHBBHBBB3x")
SM = struct.Struct("<HHBBBB")
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
    if keep_eeprom and cmd in WRITES and ado >= 0:
        data[:] = no_sii_fmmu(ado, bytes(data))
    lie = rng.random()
    if keep_eeprom and cmd in WRITES and ado >= 0 and _reaches_sii_or_fmmu(ado, dlen + 40):
        lie = 1.0  # a lying length would write the bytes after the data there, unguarded
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


# ---------------------------------------------------------------------------------------------------
# Mutated master frames (issue 21: "mutated frames (commands, addresses incl. register areas, lengths,
# SM/FMMU programming over registers)"): what a master sends during bring-up and in OP, with one or
# more fields changed, plus SyncManagers and FMMUs programmed over the register area and CoE requests
# into the mailbox so a moved SM1 gets a reply to place.

#: Register areas a mutation aims at: AL control/status, DL, SII, watchdog, FMMU, SM, DC, reserved.
REGISTER_TARGETS = (0x0000, 0x0010, 0x0100, 0x0120, 0x0130, 0x0134, 0x0140, 0x0300, 0x0400, 0x0420,
                    0x0500, 0x0502, 0x0508, 0x0600, 0x0630, 0x0800, 0x0808, 0x0810, 0x0828, 0x0900,
                    0x0910, 0x0981, 0x0990, 0x09A0, 0x0E00, 0x0F00, 0x0FF8)


def _dg(cmd: int, adp: int, ado: int, data: bytes, last: bool) -> bytes:
    return DG.pack(cmd, 0, (adp & 0xFFFF) | (ado & 0xFFFF) << 16, len(data) | (0 if last else 0x8000), 0) \
        + data + b"\0\0"


def sdo_upload_request(counter: int, index: int, sub: int) -> bytes:
    """A mailbox carrying a CoE SDO upload request (ETG.1000.6: CoE header service 2, SDO cmd 0x40)."""
    coe = struct.pack("<HBHB4x", 0x2000, 0x40, index, sub)
    return struct.pack("<HHBB", len(coe), 0, 0, 3 | (counter & 7) << 4) + coe


class MasterTemplates:
    """Datagrams a master sends to the slaves at ``stations`` with their mailboxes ``(out start, out size,
    in start, in size)`` (zeros for a slave without mailbox)."""

    def __init__(self, stations: list[int], mailboxes: list[tuple[int, int, int, int]]) -> None:
        self.stations = stations
        self.mailboxes = mailboxes

    def pick(self, rng: random.Random) -> tuple[int, int, int, bytes]:
        """(command, ADP, ADO, data) of one plausible master datagram."""
        k = rng.randrange(len(self.stations))
        st = self.stations[k]
        mo, mos, mi, mis = self.mailboxes[k]
        kind = rng.randrange(12)
        if kind == 0:
            return 7, 0, 0x0000, b"\0\0"  # BRD type: count slaves
        if kind == 1:
            return 2, -k & 0xFFFF, 0x0010, struct.pack("<H", st)  # APWR station address
        if kind == 2:
            return 4, st, 0x0130, bytes(6)  # FPRD AL status + code
        if kind == 3:
            return 5, st, 0x0120, struct.pack("<H", rng.choice((1, 2, 4, 8, 0x11, 0x12)))  # FPWR AL control
        if kind == 4:
            return 5, st, 0x0502, struct.pack("<HI", 0x0100, rng.randrange(0x40))  # SII read command
        if kind == 5:
            return 4, st, 0x0508, bytes(8)  # SII data
        if kind == 6 and mos:
            sms = SM.pack(mo, mos, 0x26, 0, 1, 0) + SM.pack(mi, mis, 0x22, 0, 1, 0)
            return 5, st, 0x0800, sms  # mailbox SyncManagers
        if kind == 7 and mos:
            req = sdo_upload_request(rng.randrange(1, 8), rng.choice((0x1000, 0x1008, 0x1018, 0x1C12, 0x1C13)),
                                     rng.randrange(3))
            return 5, st, mo, req.ljust(mos, b"\0")  # CoE request into SM0
        if kind == 8 and mis:
            return 4, st, mi, bytes(mis)  # read SM1
        if kind == 9:
            return 4, st, 0x080D, b"\0"  # SM1 status
        if kind == 10:
            return 12, 0, 0, bytes(rng.choice((8, 64, 256)))  # LRW process data
        return 5, st, 0x0400, struct.pack("<H", 2498)  # watchdog divider

    def over_registers(self, rng: random.Random) -> tuple[int, int, int, bytes]:
        """A SyncManager or an FMMU programmed over the register area (or overlapping another SM)."""
        st = rng.choice(self.stations)
        cmd = rng.choice((5, 8))  # FPWR, or BWR for every slave
        if rng.random() < 0.6:
            n = rng.choice((0, 1, 1, 1, 2, 3, 4, rng.randrange(16)))
            start = rng.choice((0x0130, 0x0120, 0x0000, 0x0800, 0x0500, 0x0FF0, 0x0134, rng.randrange(0x1000),
                                0x1000, 0x1080))  # the last two: overlapping the mailboxes
            data = SM.pack(start, rng.choice((2, 6, 16, 128, 256)), rng.choice((0x26, 0x22, 0x24, 0x20, 0x64)),
                           0, 1, 0)
            return cmd, st, 0x0800 + 8 * n, data
        n = rng.randrange(16)
        phys = rng.choice((0x0120, 0x0130, 0x0800, 0x0808, 0x0502, 0x0010, rng.randrange(0x1000)))
        data = FMMU.pack(rng.choice((0, 0x10, 0x100)), rng.choice((1, 2, 8, 16)), 0, 7, phys, 0,
                         rng.randrange(1, 4), 1)
        return cmd, st, 0x0600 + 16 * n, data


def _mutate(rng: random.Random, cmd: int, adp: int, ado: int, data: bytes) -> tuple[int, int, int, bytes]:
    for _ in range(rng.randint(1, 3)):
        what = rng.randrange(6)
        if what == 0:
            cmd = rng.randrange(1, 15) if rng.random() < 0.95 else rng.randrange(256)
        elif what == 1:
            ado = rng.choice(REGISTER_TARGETS) if rng.random() < 0.8 else rng.randrange(0x10000)
        elif what == 2:
            adp = rng.choice((0, 0xFFFF, adp + 1, adp - 1, rng.randrange(0x10000))) & 0xFFFF
        elif what == 3 and data:
            b = bytearray(data)
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            data = bytes(b)
        elif what == 4:
            data = data[:rng.randrange(len(data) + 1)] if rng.random() < 0.5 else data + rng.randbytes(
                rng.randrange(1, 64))
        else:
            ado = (ado + rng.choice((-8, -2, -1, 1, 2, 8))) & 0xFFFF
    return cmd, adp, ado, data


#: The EEPROM interface registers a write must not reach through an FMMU: control/status (0x0502, write enable
#: and command), address (0x0504) and data (0x0508) -- ET1100 data sheet II, 0x0500-0x050F.
SII_REGS = (0x0502, 0x050C)
FMMU_AREA = (0x0600, 0x0700)


def _reaches_sii_or_fmmu(ado: int, length: int) -> bool:
    """[ado, ado + length) meets the EEPROM interface or the FMMU registers."""
    return ado < FMMU_AREA[1] and ado + length > SII_REGS[0]


def _may_reach(phys: int, length: int) -> bool:
    """A writing FMMU at ``phys`` could reach :data:`SII_REGS`, now or once a later write changes the low
    byte of its physical start: only a start of 0x0600 and above, or one whose 256-byte page ends with the
    FMMU before 0x0502, is safe."""
    return phys >> 8 <= SII_REGS[1] >> 8 and (phys & 0xFF00) + 0xFF + length > SII_REGS[0]


def no_sii_fmmu(ado: int, data: bytes) -> bytes:
    """``data`` written at ``ado`` with every FMMU entry it touches kept from writing the EEPROM interface.

    An entry the write holds whole keeps writing only where it cannot reach :data:`SII_REGS`
    (:func:`_may_reach`), else its write bit (type bit 1) is cleared. A write that changes an entry in
    part keeps what it does not hold, so what it holds is made safe whatever the rest is: a physical start
    (or its high byte) is moved to process RAM, a length byte is cut to 0, a type loses its write bit; the
    low byte of a start alone cannot move a safe FMMU to the registers. No FMMU of the line then writes
    0x0502-0x050B (the master's own FMMUs start in process RAM)."""
    end = ado + len(data)
    if end <= FMMU_AREA[0] or ado >= FMMU_AREA[1]:
        return data
    b = bytearray(data)
    for base in range(max(ado, FMMU_AREA[0]) & ~0xF, min(end, FMMU_AREA[1]), 16):
        at = base - ado

        def held(off: int, n: int = 1, base: int = base) -> bool:
            return ado <= base + off and base + off + n <= end

        if held(0, 16):
            _ls, length, _sb, _eb, phys, _pb, ftype, _act = FMMU.unpack_from(b, at)
            if ftype & 2 and _may_reach(phys, length):
                b[at + 11] &= ~2 & 0xFF
            continue
        if held(9) and b[at + 9] <= SII_REGS[1] >> 8:
            b[at + 9] |= 0x10   # 0x1000 and above: process RAM
        for off in (4, 5):      # the length, or a part of it
            if held(off):
                b[at + off] = 0
        if held(11):
            b[at + 11] &= ~2 & 0xFF
    return bytes(b)


def _no_sii_write(cmd: int, ado: int, data: bytes) -> bytes:
    """Clear the SII write enable (0x0502 bit 0) a write would set, and keep every FMMU it programs from
    writing the EEPROM interface (:func:`no_sii_fmmu`): a real ESC reprograms its EEPROM too."""
    if cmd not in WRITES:
        return data
    if ado <= 0x0502 < ado + len(data):
        b = bytearray(data)
        b[0x0502 - ado] &= 0xFE
        data = bytes(b)
    return no_sii_fmmu(ado, data)


def mutated_frame(rng: random.Random, templates: MasterTemplates) -> bytes:
    """One frame of 1-4 datagrams: plausible master datagrams, mutated ones, SM/FMMU over registers,
    and now and then a lying length (datagram or EtherCAT header) or a random frame."""
    if rng.random() < 0.05:
        return storm_frame(rng, keep_eeprom=True)
    n = rng.randint(1, 4)
    parts = []
    for i in range(n):
        r = rng.random()
        if r < 0.2:
            cmd, adp, ado, data = templates.over_registers(rng)
        else:
            cmd, adp, ado, data = templates.pick(rng)
            if r < 0.75:
                cmd, adp, ado, data = _mutate(rng, cmd, adp, ado, data)
        data = _no_sii_write(cmd & 0xFF, ado, data[:1400 // n])
        raw = bytearray(_dg(cmd & 0xFF, adp, ado, data, i == n - 1))
        if rng.random() < 0.03:  # the datagram's announced length lies
            lie = rng.randrange(0x800)
            if cmd & 0xFF in WRITES and lie > len(data) and _reaches_sii_or_fmmu(ado, lie):
                lie = len(data) // 2  # longer, it would write the bytes that follow there, unguarded
            struct.pack_into("<H", raw, 6, lie | (0 if i == n - 1 else 0x8000))
        parts.append(bytes(raw))
    body = b"".join(parts)
    length = len(body) if rng.random() < 0.97 else rng.randrange(0x800)
    return (ETH + struct.pack("<H", (length & 0x7FF) | 1 << 12) + body)[:1514]


def mutated_storm(seed: int, count: int, templates: MasterTemplates) -> list[bytes]:
    rng = random.Random(seed)
    return [mutated_frame(rng, templates) for _ in range(count)]
