"""The ESC's EEPROM interface (SII, registers 0x0500-0x050F) and the EEPROM image behind it.

A master reads and writes the slave information interface through the ESC's registers: it puts a
word address into 0x0504, a command into 0x0502 (read, write, reload) and finds the data in 0x0508.
The ESC loads the configuration area (words 0..7) into PDI control, PDI configuration and station
alias at power-on and on a reload, when its checksum holds (ET1100 data sheet, "EEPROM interface").
The SII contents (categories, strings) are built in :mod:`gatewaylab.ethercat.sii`.
"""

from __future__ import annotations

from gatewaylab.ethercat.esc_registers import (
    DL_STATUS_PDI_OPERATIONAL,
    REG_DL_STATUS,
    REG_PDI_CONTROL,
    REG_SII_ADDRESS,
    REG_SII_CONTROL,
    REG_SII_DATA,
    REG_STATION_ALIAS,
    SII_BUSY,
    SII_ERR_ACK,
    SII_ERR_CHECKSUM,
    SII_ERR_WRITE_ENABLE,
    SII_READ8,
    SII_TWO_ADDRESS_BYTES,
    U16,
    U32,
    EscStats,
)
from gatewaylab.ethercat.slave_faults import SiiHold

__all__ = ["SiiInterface", "sii_checksum"]


def sii_checksum(config_area: bytes) -> int:
    """CRC-8 (poly 0x07, init 0xFF) over SII words 0..6, stored in word 7 (ET1100 data sheet)."""
    crc = 0xFF
    for b in config_area[:14]:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


class SiiInterface:
    """The EEPROM image and the register interface a master reaches it through."""

    __slots__ = ("checksum_bad", "eeprom", "hold", "mem", "stats")

    def __init__(self, mem: bytearray, stats: EscStats, eeprom: bytes, eeprom_size: int | None = None) -> None:
        self.mem = mem
        self.stats = stats
        if eeprom_size is None:
            eeprom_size = max(2048, len(eeprom))
        image = bytearray(eeprom[:eeprom_size])
        image.extend(b"\xff" * (eeprom_size - len(image)))
        #: The EEPROM contents (a master's SII writes land here and survive a power cycle).
        self.eeprom = image
        #: the last load of the configuration area failed its checksum: 0x0502 bit 11 shows it until a load
        #: succeeds or the master clears the error bits with a NOP
        self.checksum_bad = False
        #: a fault holding the interface busy (:class:`~gatewaylab.ethercat.slave_faults.SiiHold`)
        self.hold: SiiHold | None = None

    def config_bits(self) -> int:
        """0x0502 bits 5..7, fixed by the hardware: 8-byte reads, address bytes by EEPROM size."""
        return SII_READ8 | (SII_TWO_ADDRESS_BYTES if len(self.eeprom) > 2048 else 0)

    def reset(self) -> None:
        """Power-on: the control register shows the configuration bits only, then the ESC loads
        the configuration area."""
        self.hold = None
        U16.pack_into(self.mem, REG_SII_CONTROL, self.config_bits())
        self.reload()

    def reload(self) -> bool:
        """Load the SII configuration area (words 0..7); False and no load on a bad checksum."""
        e = self.eeprom
        mem = self.mem
        self.checksum_bad = sii_checksum(bytes(e[:14])) != e[14]
        if self.checksum_bad:
            ctrl = U16.unpack_from(mem, REG_SII_CONTROL)[0] | SII_ERR_CHECKSUM
            U16.pack_into(mem, REG_SII_CONTROL, ctrl)
            dl = U16.unpack_from(mem, REG_DL_STATUS)[0] & ~DL_STATUS_PDI_OPERATIONAL
            U16.pack_into(mem, REG_DL_STATUS, dl)
            return False
        mem[REG_PDI_CONTROL:REG_PDI_CONTROL + 2] = e[0:2]
        mem[0x0150:0x0152] = e[2:4]
        mem[REG_STATION_ALIAS:REG_STATION_ALIAS + 2] = e[8:10]
        ctrl = U16.unpack_from(mem, REG_SII_CONTROL)[0] & ~SII_ERR_CHECKSUM
        U16.pack_into(mem, REG_SII_CONTROL, ctrl)
        dl = U16.unpack_from(mem, REG_DL_STATUS)[0] | DL_STATUS_PDI_OPERATIONAL
        U16.pack_into(mem, REG_DL_STATUS, dl)
        return True

    def command(self) -> None:
        """The master wrote 0x0502: execute the command it holds (1 read, 2 write, 4 reload)."""
        mem = self.mem
        ctrl = U16.unpack_from(mem, REG_SII_CONTROL)[0]
        cmd = (ctrl >> 8) & 0x07
        hold = self.hold
        if hold is not None and hold.takes(cmd):
            if not hold.held:
                hold.held = ctrl     # the first waiting command is the one that runs when the hold ends
            U16.pack_into(mem, REG_SII_CONTROL, (hold.held & 0x07FF) | SII_BUSY)
            return
        # A master writes the whole word (KickCAT: 0x0100 for a read): the configuration bits stay what
        # the hardware says; errors, command and busy are cleared.
        status = self.config_bits()
        if cmd == 0:        # a NOP clears the error bits, the load's checksum error too (SOEM's "clear error bits")
            self.checksum_bad = False
            U16.pack_into(mem, REG_SII_CONTROL, status)
            return
        self.stats.sii_commands += 1
        word = U32.unpack_from(mem, REG_SII_ADDRESS)[0]
        size = len(self.eeprom)
        if cmd == 1:
            start = (word * 2) % size
            data = bytes(self.eeprom[start:start + 8]).ljust(8, b"\xff")
            mem[REG_SII_DATA:REG_SII_DATA + 8] = data
        elif cmd == 2:
            if not ctrl & 0x0001:
                status |= SII_ERR_WRITE_ENABLE
            elif word * 2 + 2 > size:
                status |= SII_ERR_ACK
            else:
                self.eeprom[word * 2:word * 2 + 2] = mem[REG_SII_DATA:REG_SII_DATA + 2]
        elif cmd == 4:
            if not self.reload():
                status |= SII_ERR_CHECKSUM
        else:
            status |= SII_ERR_ACK
        if self.checksum_bad:       # the status of the last load stays until a load succeeds
            status |= SII_ERR_CHECKSUM
        U16.pack_into(mem, REG_SII_CONTROL, status)

    def start_hold(self, hold: SiiHold) -> None:
        """A fault holds the interface: busy at once (``busy``), or from the next read (``stuck``)."""
        self.hold = hold
        if hold.mode == "busy":
            ctrl = U16.unpack_from(self.mem, REG_SII_CONTROL)[0]
            U16.pack_into(self.mem, REG_SII_CONTROL, ctrl | SII_BUSY)

    def end_hold(self) -> None:
        """The hold ends: a busy interface runs the command that waited (or just clears busy); a stuck
        read fails (acknowledge error, 0x0502 bit 13)."""
        hold = self.hold
        if hold is None:
            return
        self.hold = None
        mem = self.mem
        if hold.held and hold.mode == "busy":
            U16.pack_into(mem, REG_SII_CONTROL, hold.held)
            self.command()
            return
        status = self.config_bits() | (SII_ERR_CHECKSUM if self.checksum_bad else 0)
        U16.pack_into(mem, REG_SII_CONTROL, status | (SII_ERR_ACK if hold.held else 0))
