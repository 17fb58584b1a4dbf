"""Configuration of the in-process master (SOEM's ethercatconfig): scan, SII, AL states, mailbox SMs, mapping.

:class:`Configuration` owns the list of scanned slaves (:class:`SlaveInfo`); the mailbox, CoE,
FoE, DC and process data parts find a slave by position through it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

from gatewaylab.ethercat.datagram import Command
from gatewaylab.ethercat.errors import AlStatusError, MasterError, WorkingCounterError
from gatewaylab.ethercat.esc import (
    REG_AL_CONTROL,
    REG_AL_STATUS,
    REG_FMMU,
    REG_SII_CONTROL,
    REG_SII_DATA,
    REG_SM,
    REG_STATION_ADDRESS,
    AlState,
)
from gatewaylab.ethercat.sii import SiiInfo, parse_sii
from gatewaylab.hosts.ethercat.base import U16, U32, Port
from gatewaylab.hosts.ethercat.shared import sii_complete

if TYPE_CHECKING:
    from gatewaylab.hosts.ethercat.coe import Coe
    from gatewaylab.hosts.ethercat.process_data import ProcessImage

__all__ = ["FIRST_STATION", "FMMU_REG", "SM_REG", "Configuration", "SlaveInfo"]


FMMU_REG = struct.Struct("<IHBBHBBB3x")
SM_REG = struct.Struct("<HHBBBB")
FIRST_STATION = 0x1001


@dataclass(slots=True)
class SlaveInfo:
    """What the master learnt about one slave, so every later call addresses it by position (QEC: getVendorID ...)."""

    position: int
    station: int
    sii: SiiInfo
    output_offset: int = 0
    output_bytes: int = 0
    input_offset: int = 0
    input_bytes: int = 0
    mbx_counter: int = 0
    boot: bool = False

    @property
    def mailbox_out(self) -> tuple[int, int]:
        """(start, size) of the SM0 mailbox to write requests to: the bootstrap one in BOOT, else the standard one."""
        b = self.sii.bootstrap_mailbox
        return (b[0], b[1]) if self.boot and b[1] else self.sii.mailbox_out

    @property
    def mailbox_in(self) -> tuple[int, int]:
        """(start, size) of the SM1 mailbox to read replies from: the bootstrap one in BOOT, else the standard one."""
        b = self.sii.bootstrap_mailbox
        return (b[2], b[3]) if self.boot and b[3] else self.sii.mailbox_in

    @property
    def name(self) -> str:
        """The SII device name, to tell slaves apart in messages and ready info."""
        return self.sii.name

    @property
    def vendor_id(self) -> int:
        """The SII vendor id, to check the slave is the expected device."""
        return self.sii.vendor_id

    @property
    def product_code(self) -> int:
        """The SII product code, to check the slave is the expected device."""
        return self.sii.product_code

    @property
    def revision(self) -> int:
        """The SII revision number, to check the slave is the expected device version."""
        return self.sii.revision

    @property
    def serial(self) -> int:
        """The SII serial number, to tell identical devices apart."""
        return self.sii.serial


def _pd_sms(s: SlaveInfo) -> tuple[tuple[int, int] | None, tuple[int, int] | None]:
    """(start, SM index) of the outputs and inputs SyncManagers from the SII (types 3 and 4); None for one the
    SII does not list (an inputs-only terminal such as an EL1008 has only its inputs SyncManager, SM0)."""
    outs = [(sm[0], i) for i, sm in enumerate(s.sii.sync_managers) if sm[4] == 3]
    ins = [(sm[0], i) for i, sm in enumerate(s.sii.sync_managers) if sm[4] == 4]
    if not outs and not ins:
        raise MasterError(f"slave {s.position} has no process data SyncManagers in its SII")
    return (outs[0] if outs else None), (ins[0] if ins else None)


class Configuration:
    """Finds and configures the slaves: addresses, SII, AL states, mailbox and process data SMs/FMMUs."""

    def __init__(self, port: Port) -> None:
        self.port = port
        #: The slaves of the last scan, by position (the other parts look them up through :meth:`slave`).
        self.slaves: list[SlaveInfo] = []

    # ------------------------------------------------------------------ scan, SII
    def scan(self) -> list[SlaveInfo]:
        """Find the slaves (BRD), give them station addresses (APWR) and read their SII: the start of every session."""
        port = self.port
        count = port.phys(Command.BRD, 0, 0x0000, b"\0\0").wkc
        port.phys(Command.BWR, 0, REG_AL_CONTROL, U16.pack(AlState.INIT | 0x10))
        port.phys(Command.BWR, 0, REG_FMMU, bytes(16 * 16))
        port.phys(Command.BWR, 0, REG_SM, bytes(8 * 16))
        self.slaves = []
        for pos in range(count):
            station = FIRST_STATION + pos
            d = port.phys(Command.APWR, -pos, REG_STATION_ADDRESS, U16.pack(station))
            if d.wkc != 1:
                raise WorkingCounterError(f"no slave at position {pos}", d.wkc)
            self.slaves.append(SlaveInfo(pos, station, parse_sii(self.read_sii(station))))
        return self.slaves

    def read_sii(self, station: int, max_bytes: int = 65536) -> bytes:
        """The SII image up to its END category, which tells the master the slave's mailboxes and SyncManagers."""
        out = bytearray()
        while len(out) < max_bytes:
            out += self.sii_read8(station, len(out) // 2)
            if len(out) >= 0x84 and sii_complete(out):
                break
        return bytes(out)

    def sii_read8(self, station: int, word: int) -> bytes:
        """Read 8 bytes of the SII through the EEPROM interface, the unit of every SII read."""
        self.port.fpwr(station, REG_SII_CONTROL, U16.pack(0x0100) + U32.pack(word))
        status = U16.unpack(self.port.fprd(station, REG_SII_CONTROL, 2))[0]
        if status & 0x7800:
            raise WorkingCounterError(f"SII read error status 0x{status:04X}", status)
        return self.port.fprd(station, REG_SII_DATA, 8)

    def sii_write(self, station: int, word: int, value: int) -> int:
        """Write one SII word through the EEPROM interface (to test write protection and errors); returns its status."""
        self.port.fpwr(station, REG_SII_DATA, U16.pack(value))
        self.port.fpwr(station, REG_SII_CONTROL, U16.pack(0x0201) + U32.pack(word))
        return int(U16.unpack(self.port.fprd(station, REG_SII_CONTROL, 2))[0])

    def slave(self, position: int) -> SlaveInfo:
        """The scanned slave at a position, or a MasterError that says to scan first."""
        if not 0 <= position < len(self.slaves):
            raise MasterError(f"no slave at position {position} (scan first)")
        return self.slaves[position]

    # ------------------------------------------------------------------ states
    def al_status(self, position: int) -> tuple[int, int]:
        """(AL status, AL status code) of one slave: how a master learns a state change failed and why."""
        raw = self.port.fprd(self.slave(position).station, REG_AL_STATUS, 6)
        return U16.unpack_from(raw, 0)[0], U16.unpack_from(raw, 4)[0]

    def request_state(self, position: int, state: AlState, ack: bool = False) -> AlState:
        """Move one slave to an AL state (configuring its mailbox first), raising AlStatusError with its code."""
        s = self.slave(position)
        if state in (AlState.PREOP, AlState.BOOT):
            self.configure_mailbox(s, boot=state == AlState.BOOT)
        self.port.fpwr(s.station, REG_AL_CONTROL, U16.pack(int(state) | (0x10 if ack else 0)))
        status, code = self.al_status(position)
        s.boot = (status & 0x0F) == AlState.BOOT
        if status & 0x10 or (status & 0x0F) != state:
            raise AlStatusError(f"slave {position} refused {state.name}: AL status 0x{status:02X}", code)
        return AlState(status & 0x0F)

    def set_state(self, state: AlState) -> None:
        """Move every slave to an AL state, as masters do for the whole segment."""
        for s in self.slaves:
            self.request_state(s.position, state)

    def configure_mailbox(self, s: SlaveInfo, boot: bool = False) -> None:
        """Program SM0/SM1 as the standard (or in BOOT the bootstrap) mailbox, before PREOP/BOOT is requested."""
        if s.sii.mailbox_protocols == 0:
            return
        b = s.sii.bootstrap_mailbox
        (mo, mos), (mi, mis) = ((b[0], b[1]), (b[2], b[3])) if boot and b[1] else (s.sii.mailbox_out,
                                                                                    s.sii.mailbox_in)
        sms = SM_REG.pack(mo, mos, 0x26, 0, 1, 0) + SM_REG.pack(mi, mis, 0x22, 0, 1, 0)
        self.port.fpwr(s.station, REG_SM, sms)

    # ------------------------------------------------------------------ mapping
    def config_map(self, coe: Coe, image: ProcessImage) -> int:
        """Read each slave's PDO assignment by SDO, program SM2/SM3 and FMMU0/1; returns the process image size."""
        out_off = 0
        for s in self.slaves:
            s.output_bytes = self._pdo_bytes(coe, s, 0x1C12)
            s.output_offset = out_off
            out_off += s.output_bytes
        in_off = out_off
        for s in self.slaves:
            s.input_bytes = self._pdo_bytes(coe, s, 0x1C13)
            s.input_offset = in_off
            in_off += s.input_bytes
        for s in self.slaves:
            o_sm, i_sm = _pd_sms(s)
            fmmus = b""
            for sm, size, offset, direction in ((o_sm, s.output_bytes, s.output_offset, 2),
                                                (i_sm, s.input_bytes, s.input_offset, 1)):
                start = sm[0] if sm is not None else 0
                if sm is not None:
                    ctrl = s.sii.sync_managers[sm[1]][2]
                    self.port.fpwr(s.station, REG_SM + 8 * sm[1],
                                   SM_REG.pack(start, size, ctrl, 0, 1 if size else 0, 0))
                fmmus += FMMU_REG.pack(offset, size, 0, 7, start, 0, direction, 1 if size and sm is not None else 0)
            self.port.fpwr(s.station, REG_FMMU, fmmus)
        image.lay_out(out_off, in_off)
        return in_off

    @staticmethod
    def _pdo_bytes(coe: Coe, s: SlaveInfo, assign: int) -> int:
        """Bytes of one direction's process data: from the PDO assignment by SDO, else from the SII SM sizes."""
        if not s.sii.coe_details:
            return sum(ln for _st, ln, _c, _e, t in s.sii.sync_managers if t == (3 if assign == 0x1C12 else 4))
        bits = 0
        for i in range(1, coe.sdo_upload8(s.position, assign, 0) + 1):
            pdo = coe.sdo_upload16(s.position, assign, i)
            for j in range(1, coe.sdo_upload8(s.position, pdo, 0) + 1):
                bits += coe.sdo_upload32(s.position, pdo, j) & 0xFF
        return (bits + 7) // 8
