"""Emulated ET1100-class EtherCAT Slave Controller: registers, DPRAM, SyncManagers, FMMUs, AL, SII, DC.

Sans-I/O: ``process_datagram`` works in place on a frame buffer (as the real ESC does on the fly);
everything the slave application must react to goes to an :class:`EscApplication`. Time comes from
the injected clock (SM watchdog, DC system time, SYNC0). Register map and bit meanings follow the
ET1100 hardware data sheet; the state machine follows IDX guide 4.2 (tables 4-16..4-18).
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Protocol

from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.ethercat.errors import AlStatusCode

U8 = struct.Struct("<B")
U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
U64 = struct.Struct("<Q")
FMMU_REG = struct.Struct("<IHBBHBBB3x")
SM_REG = struct.Struct("<HHBBBB")

# Register addresses (ET1100 data sheet section II).
REG_TYPE = 0x0000
REG_FEATURES = 0x0008
REG_STATION_ADDRESS = 0x0010
REG_STATION_ALIAS = 0x0012
REG_DL_CONTROL = 0x0100
REG_DL_STATUS = 0x0110
REG_AL_CONTROL = 0x0120
REG_AL_STATUS = 0x0130
REG_AL_STATUS_CODE = 0x0134
REG_PDI_CONTROL = 0x0140
REG_RX_ERROR = 0x0300
REG_WD_DIVIDER = 0x0400
REG_WD_TIME_PDI = 0x0410
REG_WD_TIME_SM = 0x0420
REG_WD_STATUS_SM = 0x0440
REG_WD_COUNTER_SM = 0x0442
REG_SII_CONFIG = 0x0500
REG_SII_CONTROL = 0x0502
REG_SII_ADDRESS = 0x0504
REG_SII_DATA = 0x0508
REG_FMMU = 0x0600
REG_SM = 0x0800
REG_DC_RECV_TIME = 0x0900
REG_DC_SYSTEM_TIME = 0x0910
REG_DC_RECV_TIME_PU = 0x0918
REG_DC_SYSTEM_OFFSET = 0x0920
REG_DC_SYSTEM_DELAY = 0x0928
REG_DC_ACTIVATION = 0x0981
REG_DC_SYNC0_STATUS = 0x098E
REG_DC_START_TIME = 0x0990
REG_DC_SYNC0_CYCLE = 0x09A0
REG_DC_SYNC1_CYCLE = 0x09A4
RAM_START = 0x1000
#: Shortest SYNC0 period the emulated firmware follows (a shorter 0x09A0 is raised to it): a Python
#: PDI cannot take interrupts faster, and a 1 ns cycle would otherwise flood the clock (docs/decisions.md).
SYNC0_MIN_CYCLE_NS = 10_000

AL_ERROR = 0x10
AL_ACK = 0x10
SII_BUSY = 0x8000
SII_ERR_CHECKSUM = 0x0800
SII_ERR_ACK = 0x2000
SII_ERR_WRITE_ENABLE = 0x4000
SII_READ8 = 0x0040
#: 0x0502 bit 7: EEPROM above 16 kbit, two address bytes (ET1100: bits 5..7 are read-only configuration)
SII_TWO_ADDRESS_BYTES = 0x0080
SM_STATUS_FULL = 0x08
SM_STATUS_WRITE_EVENT = 0x01
SM_STATUS_READ_EVENT = 0x02
SM_CTRL_MAILBOX = 0x02
SM_CTRL_ECAT_WRITE = 0x04
SM_CTRL_WATCHDOG = 0x40
SM_ACT_ENABLE = 0x01
SM_ACT_REPEAT = 0x02
SM_PDI_DISABLE = 0x01
SM_PDI_REPEAT_ACK = 0x02
DL_STATUS_PDI_OPERATIONAL = 0x0001
DL_STATUS_WD_OK = 0x0002

# Commands by number (datagram.Command), inlined on the hot path.
_APRD, _APWR, _APRW, _FPRD, _FPWR, _FPRW, _BRD, _BWR, _BRW, _LRD, _LWR, _LRW, _ARMW, _FRMW = range(1, 15)


class AlState(enum.IntEnum):
    """EtherCAT states as coded in AL control / AL status bits 3..0 (IDX guide table 4-18)."""

    INIT = 0x01
    PREOP = 0x02
    BOOT = 0x03
    SAFEOP = 0x04
    OP = 0x08


#: Legal transitions (IDX guide table 4-17); anything else is refused with 0x0011.
AL_TRANSITIONS: frozenset[tuple[AlState, AlState]] = frozenset({
    (AlState.INIT, AlState.PREOP), (AlState.INIT, AlState.BOOT),
    (AlState.PREOP, AlState.INIT), (AlState.PREOP, AlState.SAFEOP),
    (AlState.SAFEOP, AlState.PREOP), (AlState.SAFEOP, AlState.OP), (AlState.SAFEOP, AlState.INIT),
    (AlState.OP, AlState.SAFEOP), (AlState.OP, AlState.PREOP), (AlState.OP, AlState.INIT),
    (AlState.BOOT, AlState.INIT),
})
_RANK = {AlState.INIT: 0, AlState.PREOP: 1, AlState.BOOT: 1, AlState.SAFEOP: 2, AlState.OP: 3}


class EscApplication(Protocol):
    """What the ESC asks of the slave behind it (the real ESC raises PDI interrupts instead)."""

    def check_transition(self, old: AlState, new: AlState) -> int: ...
    def state_changed(self, old: AlState, new: AlState, code: int) -> None: ...
    def sm_written(self, sm: int, data: bytes) -> None: ...
    def sm_read(self, sm: int) -> None: ...
    def sm_changed(self) -> None: ...
    def sync0(self, t: float) -> None: ...


@dataclass(frozen=True, slots=True)
class SmConfig:
    """A SyncManager as the master configured it (registers 0x0800 + 8n)."""

    index: int
    start: int
    length: int
    control: int
    activate: int

    @property
    def enabled(self) -> bool:
        return bool(self.activate & SM_ACT_ENABLE) and self.length > 0

    @property
    def mailbox(self) -> bool:
        return (self.control & 0x03) == SM_CTRL_MAILBOX

    @property
    def ecat_writes(self) -> bool:
        return bool(self.control & SM_CTRL_ECAT_WRITE)


class _Sm:
    __slots__ = ("ecat_writes", "end", "index", "mailbox", "start", "status_addr", "watchdog")

    def __init__(self, cfg: SmConfig) -> None:
        self.index = cfg.index
        self.start = cfg.start
        self.end = cfg.start + cfg.length
        self.mailbox = cfg.mailbox
        self.ecat_writes = cfg.ecat_writes
        self.watchdog = bool(cfg.control & SM_CTRL_WATCHDOG)
        self.status_addr = REG_SM + 8 * cfg.index + 5


class _Fmmu:
    __slots__ = ("lbit0", "lbit1", "lend", "lstart", "pbit", "phys", "read", "simple", "write")

    def __init__(self, lstart: int, length: int, lbit0: int, lbit1: int, phys: int, pbit: int,
                 ftype: int) -> None:
        self.lstart = lstart
        self.lend = lstart + length
        self.phys = phys
        self.read = bool(ftype & 1)
        self.write = bool(ftype & 2)
        self.lbit0 = lbit0
        self.lbit1 = lbit1
        self.pbit = pbit
        self.simple = lbit0 == 0 and lbit1 == 7 and pbit == 0


@dataclass(slots=True)
class EscStats:
    """Counters a test or a user can read (frames seen by this ESC and what it refused)."""

    datagrams: int = 0
    #: Datagrams whose processing raised (Segment isolates them: the frame's other datagrams still run).
    datagram_errors: int = 0
    refused_accesses: int = 0
    #: SyncManagers the master enabled that the ESC did not activate (buffer in the register area, or
    #: overlapping a lower SyncManager), counted on every configuration write that leaves one so.
    refused_sms: int = 0
    al_refusals: int = 0
    watchdog_expiries: int = 0
    sii_commands: int = 0


def sii_checksum(config_area: bytes) -> int:
    """CRC-8 (poly 0x07, init 0xFF) over SII words 0..6, stored in word 7 (ET1100 data sheet)."""
    crc = 0xFF
    for b in config_area[:14]:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


class Esc:
    """One slave controller. ``app`` gets the PDI-side events; ``eeprom`` is the SII image."""

    def __init__(self, clock: Clock, eeprom: bytes, app: EscApplication, *, ram_size: int = 0x2000,
                 fmmus: int = 16, sms: int = 16, dc: bool = True, eeprom_size: int | None = None,
                 firmware_sms: int = 4) -> None:
        self.clock = clock
        self.app = app
        self.stats = EscStats()
        self.mem = bytearray(RAM_START + ram_size)
        self._memlen = len(self.mem)
        self.n_fmmu = fmmus
        self.n_sm = sms
        #: SyncManagers the slave firmware serves (mailbox 0/1, process data 2/3); the others are
        #: deactivated from the PDI side on every INIT request (see ``_release_unused_sms``).
        self.firmware_sms = min(firmware_sms, sms)
        self.dc = dc
        if eeprom_size is None:
            eeprom_size = max(2048, len(eeprom))
        image = bytearray(eeprom[:eeprom_size])
        image.extend(b"\xff" * (eeprom_size - len(image)))
        self.eeprom = image
        self._fmmus: tuple[_Fmmu, ...] = ()
        self._sms: tuple[_Sm, ...] = ()
        self._active_sms: frozenset[int] = frozenset()
        self._ro = bytearray(RAM_START)
        self._downstream = 0
        self._wd_last = 0.0
        self._wd_timer: TimerHandle | None = None
        self._sync0_timer: TimerHandle | None = None
        self._sync0_next = 0.0
        self._sync0_cycle = 0.0
        self._mbx_last: bytes = b""
        self.pdi_outputs: dict[int, bytes] = {}
        #: Powered off / link down (a device resetting itself): datagrams pass untouched, as if the
        #: slave were not in the line (see :meth:`power_cycle`).
        self.offline = False
        self._reset_registers()

    # ------------------------------------------------------------------ reset / configuration
    def _reset_registers(self) -> None:
        m = self.mem
        m[REG_TYPE] = 0x11  # ET1100
        m[0x0001] = 0x00
        U16.pack_into(m, 0x0002, 0x0002)
        m[0x0004] = self.n_fmmu
        m[0x0005] = self.n_sm
        m[0x0006] = (self._memlen - RAM_START) // 1024
        m[0x0007] = 0x0F  # ports 0 and 1 MII
        U16.pack_into(m, REG_FEATURES, 0x000C if self.dc else 0x0000)  # DC + 64-bit DC
        U32.pack_into(m, REG_DL_CONTROL, 0x00000001)
        U16.pack_into(m, REG_AL_STATUS, AlState.INIT)
        U16.pack_into(m, REG_WD_DIVIDER, 2498)  # 100 us watchdog tick
        U16.pack_into(m, REG_WD_TIME_PDI, 1000)
        U16.pack_into(m, REG_WD_TIME_SM, 1000)  # 100 ms
        # 8-byte reads; 'two address bytes' (bit 7) for EEPROMs above 16 kbit
        U16.pack_into(m, REG_SII_CONTROL, self._sii_config_bits())
        # ECAT-side read-only registers (ET1100 data sheet section II, "ECAT r/-"): information,
        # DL status, AL status and code, PDI control/configuration, AL event mask and request,
        # EEPROM PDI access state, watchdog status, DC receive time of the processing unit, SYNC status.
        for lo, hi in ((0x0000, 0x0010), (0x0110, 0x0112),
                       (0x0130, 0x0138), (0x0140, 0x0142), (0x0150, 0x0154), (0x0204, 0x0208),
                       (0x0210, 0x0214), (0x0220, 0x0228), (0x0501, 0x0502), (0x0440, 0x0444),
                       (0x0918, 0x0920), (REG_DC_SYNC0_STATUS, REG_DC_SYNC0_STATUS + 2)):
            self._ro[lo:hi] = b"\x01" * (hi - lo)
        for i in range(self.n_sm):
            self._ro[REG_SM + 8 * i + 5] = 1
            self._ro[REG_SM + 8 * i + 7] = 1
        self.reload_eeprom()
        self._update_dl_status()

    def set_downstream(self, count: int) -> None:
        """How many slaves follow this one in the line (sets DL status ports and DC delays)."""
        self._downstream = count
        self._update_dl_status()

    def _update_dl_status(self) -> None:
        status = U16.unpack_from(self.mem, REG_DL_STATUS)[0] & 0x0003
        status |= 0x0010 | 0x0200  # port 0: link + communication
        status |= (0x0020 | 0x0800) if self._downstream else 0x0400  # port 1 open or loop closed
        U16.pack_into(self.mem, REG_DL_STATUS, status)

    def reload_eeprom(self) -> bool:
        """Load the SII configuration area (words 0..7); False and no load on a bad checksum."""
        e = self.eeprom
        if sii_checksum(bytes(e[:14])) != e[14]:
            ctrl = U16.unpack_from(self.mem, REG_SII_CONTROL)[0] | SII_ERR_CHECKSUM
            U16.pack_into(self.mem, REG_SII_CONTROL, ctrl)
            dl = U16.unpack_from(self.mem, REG_DL_STATUS)[0] & ~DL_STATUS_PDI_OPERATIONAL
            U16.pack_into(self.mem, REG_DL_STATUS, dl)
            return False
        self.mem[REG_PDI_CONTROL:REG_PDI_CONTROL + 2] = e[0:2]
        self.mem[0x0150:0x0152] = e[2:4]
        self.mem[REG_STATION_ALIAS:REG_STATION_ALIAS + 2] = e[8:10]
        dl = U16.unpack_from(self.mem, REG_DL_STATUS)[0] | DL_STATUS_PDI_OPERATIONAL
        U16.pack_into(self.mem, REG_DL_STATUS, dl)
        return True

    # ------------------------------------------------------------------ simple accessors
    @property
    def station_address(self) -> int:
        return int(U16.unpack_from(self.mem, REG_STATION_ADDRESS)[0])

    @property
    def al_status(self) -> int:
        return int(U16.unpack_from(self.mem, REG_AL_STATUS)[0])

    @property
    def al_state(self) -> AlState:
        return AlState(self.al_status & 0x0F)

    @property
    def al_status_code(self) -> int:
        return int(U16.unpack_from(self.mem, REG_AL_STATUS_CODE)[0])

    def sm_config(self, index: int) -> SmConfig:
        start, length, control, _status, activate, _pdi = SM_REG.unpack_from(self.mem, REG_SM + 8 * index)
        return SmConfig(index, start, length, control, activate)

    def sm_in_use(self, index: int) -> bool:
        """Enabled by the master and not deactivated by the PDI (0x0807 + 8n bit 0)."""
        return self.sm_config(index).enabled and not self.mem[REG_SM + 8 * index + 7] & SM_PDI_DISABLE

    def sm_status(self, index: int) -> int:
        return self.mem[REG_SM + 8 * index + 5]

    def fmmu_config(self, index: int) -> tuple[int, int, int, int, int, int, int, int]:
        """(logical start, length, start bit, stop bit, physical start, physical bit, type, active)."""
        v = FMMU_REG.unpack_from(self.mem, REG_FMMU + 16 * index)
        return (v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7])

    def local_time_ns(self) -> int:
        return round(self.clock.now() * 1e9)

    def system_time_ns(self) -> int:
        offset: int = U64.unpack_from(self.mem, REG_DC_SYSTEM_OFFSET)[0]
        return (self.local_time_ns() + offset) & 0xFFFFFFFFFFFFFFFF

    # ------------------------------------------------------------------ PDI side (the slave application)
    def _store(self, address: int, data: bytes | bytearray) -> None:
        """Write process RAM without ever growing it or reaching the registers: bytes past the end
        of process RAM are dropped (a SyncManager a master placed there has no memory behind it),
        bytes below 0x1000 too (registers and process RAM are separate, ET1100 data sheet II)."""
        if address < RAM_START:
            data = data[RAM_START - address:]
            address = RAM_START
        end = min(address + len(data), self._memlen)
        if address < end:
            self.mem[address:end] = data[:end - address]

    def pdi_write(self, address: int, data: bytes) -> None:
        """The application writes process RAM (inputs buffer); no ECAT-side effects."""
        self._store(address, data)

    def pdi_read(self, address: int, length: int) -> bytes:
        return bytes(self.mem[address:address + length])

    def sm_active(self, index: int) -> bool:
        """The ESC runs this SyncManager: enabled by the master, not deactivated by the PDI, its
        buffer in process RAM and clear of every lower SyncManager (see ``_rebuild_sms``)."""
        return index in self._active_sms

    def mailbox_put(self, sm_index: int, message: bytes) -> bool:
        """Put a message into the (empty) slave-to-master mailbox; False when it is still full or the
        ESC does not run that SyncManager (e.g. a master placed it over the registers)."""
        cfg = self.sm_config(sm_index)
        status_addr = REG_SM + 8 * sm_index + 5
        if self.mem[status_addr] & SM_STATUS_FULL or sm_index not in self._active_sms:
            return False
        buf = message[:cfg.length].ljust(cfg.length, b"\x00")
        self._store(cfg.start, buf)
        self.mem[status_addr] |= SM_STATUS_FULL
        self._mbx_last = buf
        return True

    def sm_set_full(self, sm_index: int) -> None:
        """The PDI filled a 1-buffer SM (inputs written for the master to read)."""
        self.mem[REG_SM + 8 * sm_index + 5] |= SM_STATUS_FULL

    def mailbox_full(self, sm_index: int) -> bool:
        return bool(self.mem[REG_SM + 8 * sm_index + 5] & SM_STATUS_FULL)

    def mailbox_clear(self, sm_index: int) -> None:
        self.mem[REG_SM + 8 * sm_index + 5] &= ~SM_STATUS_FULL & 0xFF

    def force_state(self, state: AlState, code: int = 0) -> None:
        """The application changes state by itself (error: SAFEOP + error flag + code)."""
        old = self.al_state
        U16.pack_into(self.mem, REG_AL_STATUS, int(state) | (AL_ERROR if code else 0))
        U16.pack_into(self.mem, REG_AL_STATUS_CODE, code)
        if state != AlState.OP:
            self._stop_watchdog()
        if old != state:
            self.app.state_changed(old, state, code)

    def power_cycle(self) -> None:
        """Power-on reset (a device restarting after a firmware update): registers and process RAM
        cleared (station address, SyncManagers, FMMUs, DC lost), timers stopped, SII reloaded, INIT."""
        old = self.al_state
        self._stop_watchdog()
        if self._sync0_timer is not None:
            self._sync0_timer.cancel()
            self._sync0_timer = None
        self.mem[:] = bytes(len(self.mem))
        self._fmmus = ()
        self._sms = ()
        self._active_sms = frozenset()
        self.pdi_outputs.clear()
        self._mbx_last = b""
        self._reset_registers()
        if old != AlState.INIT:
            self.app.state_changed(old, AlState.INIT, 0)

    # ------------------------------------------------------------------ ECAT-side memory access
    def ecat_read(self, address: int, length: int) -> bytes | None:
        """A master read; None when the ESC refuses it (empty mailbox): no WKC increment."""
        end = address + length
        mem = self.mem
        if address < RAM_START:
            if end > 0x0900 and address < 0x09A0:
                self._refresh_dc(address, end)
            if end > self._memlen:
                return bytes(mem[address:self._memlen]).ljust(length, b"\x00")
            return bytes(mem[address:end])
        hit: list[_Sm] | None = None
        for sm in self._sms:
            if sm.start < end and address < sm.end:
                if sm.mailbox and not sm.ecat_writes and not mem[sm.status_addr] & SM_STATUS_FULL:
                    self.stats.refused_accesses += 1
                    return None
                if hit is None:
                    hit = []
                hit.append(sm)
        data = bytes(mem[address:end]) if end <= self._memlen else \
            bytes(mem[address:self._memlen]).ljust(length, b"\x00")
        if hit is not None:
            for sm in hit:
                if not sm.ecat_writes and end >= sm.end:
                    if sm.mailbox:  # 1-buffer mode: the buffer is free again
                        mem[sm.status_addr] &= ~SM_STATUS_FULL & 0xFF
                    self.app.sm_read(sm.index)
        return data

    def ecat_write(self, address: int, data: bytes | bytearray | memoryview) -> bool:
        """A master write; False when refused (full mailbox): no WKC increment."""
        length = len(data)
        end = address + length
        mem = self.mem
        if address < RAM_START:
            self._register_write(address, end, data)
            if end <= RAM_START:
                return True
            data = bytes(data[RAM_START - address:])
            address = RAM_START
        hit: list[_Sm] | None = None
        for sm in self._sms:
            if sm.start < end and address < sm.end:
                if sm.mailbox and sm.ecat_writes and mem[sm.status_addr] & SM_STATUS_FULL:
                    self.stats.refused_accesses += 1
                    return False
                if hit is None:
                    hit = []
                hit.append(sm)
        if end > self._memlen:
            data = bytes(data[:max(0, self._memlen - address)])
            end = self._memlen
        mem[address:end] = data
        if hit is not None:
            for sm in hit:
                if sm.ecat_writes and end >= sm.end:
                    # The buffer is complete: 1-buffer mode marks it full until the PDI reads it,
                    # 3-buffer mode hands the PDI the newest complete buffer.
                    mem[sm.status_addr] |= SM_STATUS_FULL if sm.mailbox else SM_STATUS_WRITE_EVENT
                    data_out = bytes(mem[sm.start:sm.end])
                    self.pdi_outputs[sm.index] = data_out
                    if sm.watchdog:
                        self._wd_last = self.clock.now()
                        self.mem[REG_WD_STATUS_SM] = 1
                    self.app.sm_written(sm.index, data_out)
        return True

    def _register_write(self, address: int, end: int, data: bytes | bytearray | memoryview) -> None:
        mem = self.mem
        stop = min(end, RAM_START)
        old = bytes(mem[address:stop])
        mem[address:stop] = data[:stop - address]
        ro = self._ro
        if any(ro[address:stop]):
            for a in range(address, stop):
                if ro[a]:
                    mem[a] = old[a - address]
        if end > REG_SII_CONTROL and address < REG_SII_CONTROL + 2:
            self._sii_command()
        if end > REG_AL_CONTROL and address < REG_AL_CONTROL + 2:
            self._al_control(U16.unpack_from(mem, REG_AL_CONTROL)[0])
        if end > REG_FMMU and address < REG_FMMU + 16 * self.n_fmmu:
            self._rebuild_fmmus()
        if end > REG_SM and address < REG_SM + 8 * self.n_sm:
            self._rebuild_sms(old, address)
        if end > 0x0900 and address < 0x09B0:
            self._dc_write(address, end, old)

    # ------------------------------------------------------------------ datagram processing
    def process_datagram(self, buf: bytearray, pos: int, cmd: int, dlen: int) -> None:
        """Execute one datagram of a frame in place (auto-increment address, data, working counter)."""
        self.stats.datagrams += 1
        if cmd == 0 or cmd > _FRMW or self.offline:
            return  # NOP (and anything unknown) passes untouched; so does everything while offline
        off = pos + 10
        wkc_at = off + dlen
        inc = 0
        if cmd >= _LRD and cmd <= _LRW:
            inc = self._logical(buf, off, U32.unpack_from(buf, pos + 2)[0], dlen, cmd)
        elif cmd <= _APRW or cmd == _ARMW:
            adp = U16.unpack_from(buf, pos + 2)[0]
            U16.pack_into(buf, pos + 2, (adp + 1) & 0xFFFF)
            ado = U16.unpack_from(buf, pos + 4)[0]
            if cmd == _ARMW:
                inc = self._rmw(buf, off, ado, dlen, adp == 0)
            elif adp == 0:
                inc = self._physical(buf, off, ado, dlen, cmd - _APRD)
        elif cmd <= _FPRW or cmd == _FRMW:
            adp, ado = U16.unpack_from(buf, pos + 2)[0], U16.unpack_from(buf, pos + 4)[0]
            mine = adp == self.station_address or (
                bool(self.mem[REG_DL_CONTROL + 3] & 0x01) and adp == U16.unpack_from(self.mem, REG_STATION_ALIAS)[0])
            if cmd == _FRMW:
                inc = self._rmw(buf, off, ado, dlen, mine)
            elif mine:
                inc = self._physical(buf, off, ado, dlen, cmd - _FPRD)
        elif cmd <= _BRW:
            adp = U16.unpack_from(buf, pos + 2)[0]
            U16.pack_into(buf, pos + 2, (adp + 1) & 0xFFFF)
            inc = self._broadcast(buf, off, U16.unpack_from(buf, pos + 4)[0], dlen, cmd - _BRD)
        if inc:
            U16.pack_into(buf, wkc_at, (U16.unpack_from(buf, wkc_at)[0] + inc) & 0xFFFF)

    def _physical(self, buf: bytearray, off: int, ado: int, dlen: int, kind: int) -> int:
        """kind 0 read, 1 write, 2 read+write (swap)."""
        if kind == 0:
            data = self.ecat_read(ado, dlen)
            if data is None:
                return 0
            buf[off:off + dlen] = data
            return 1
        if kind == 1:
            return 1 if self.ecat_write(ado, bytes(buf[off:off + dlen])) else 0
        incoming = bytes(buf[off:off + dlen])
        data = self.ecat_read(ado, dlen)
        inc = 0
        if data is not None:
            buf[off:off + dlen] = data
            inc = 1
        if self.ecat_write(ado, incoming):
            inc += 2
        return inc

    def _broadcast(self, buf: bytearray, off: int, ado: int, dlen: int, kind: int) -> int:
        if kind == 1:
            return 1 if self.ecat_write(ado, bytes(buf[off:off + dlen])) else 0
        incoming = bytes(buf[off:off + dlen])
        data = self.ecat_read(ado, dlen)
        inc = 0
        if data is not None:
            buf[off:off + dlen] = bytes(a | b for a, b in zip(incoming, data))
            inc = 1
        if kind == 2 and self.ecat_write(ado, incoming):
            inc += 2
        return inc

    def _rmw(self, buf: bytearray, off: int, ado: int, dlen: int, addressed: bool) -> int:
        if addressed:
            data = self.ecat_read(ado, dlen)
            if data is None:
                return 0
            buf[off:off + dlen] = data
            return 1
        return 1 if self.ecat_write(ado, bytes(buf[off:off + dlen])) else 0

    def _logical(self, buf: bytearray, off: int, laddr: int, dlen: int, cmd: int) -> int:
        fmmus = self._fmmus
        if not fmmus:
            return 0
        lend = laddr + dlen
        rd = wr = False
        if cmd != _LRD:  # writes first: the frame's data as it arrived at this slave
            for f in fmmus:
                if f.write and f.lstart < lend and laddr < f.lend and self._fmmu_write(f, buf, off, laddr, lend):
                    wr = True
        if cmd != _LWR:
            for f in fmmus:
                if f.read and f.lstart < lend and laddr < f.lend and self._fmmu_read(f, buf, off, laddr, lend):
                    rd = True
        if cmd == _LWR:
            return 1 if wr else 0
        return (1 if rd else 0) + (2 if wr else 0)

    def _fmmu_write(self, f: _Fmmu, buf: bytearray, off: int, laddr: int, lend: int) -> bool:
        if f.simple:
            o0 = max(laddr, f.lstart)
            o1 = min(lend, f.lend)
            fo = off + o0 - laddr
            return self.ecat_write(f.phys + o0 - f.lstart, bytes(buf[fo:fo + o1 - o0]))
        bits = self._fmmu_bits(f, laddr, lend)
        if not bits:
            return False
        p0 = bits[0][1] >> 3
        p1 = (bits[-1][1] >> 3) + 1
        # Bits mapped past the end of process RAM read as 0; ecat_write drops them (ET1100 II:
        # accesses to non-existent memory are ignored).
        cur = bytearray(self.mem[p0:p1]).ljust(p1 - p0, b"\x00")
        for lbit, pbit in bits:
            v = (buf[off + (lbit >> 3) - laddr] >> (lbit & 7)) & 1
            i = (pbit >> 3) - p0
            cur[i] = (cur[i] & ~(1 << (pbit & 7))) | (v << (pbit & 7))
        return self.ecat_write(p0, cur)

    def _fmmu_read(self, f: _Fmmu, buf: bytearray, off: int, laddr: int, lend: int) -> bool:
        if f.simple:
            o0 = max(laddr, f.lstart)
            o1 = min(lend, f.lend)
            data = self.ecat_read(f.phys + o0 - f.lstart, o1 - o0)
            if data is None:
                return False
            fo = off + o0 - laddr
            buf[fo:fo + o1 - o0] = data
            return True
        bits = self._fmmu_bits(f, laddr, lend)
        if not bits:
            return False
        p0 = bits[0][1] >> 3
        p1 = (bits[-1][1] >> 3) + 1
        data = self.ecat_read(p0, p1 - p0)
        if data is None:
            return False
        for lbit, pbit in bits:
            v = (data[(pbit >> 3) - p0] >> (pbit & 7)) & 1
            i = off + (lbit >> 3) - laddr
            buf[i] = (buf[i] & ~(1 << (lbit & 7))) | (v << (lbit & 7))
        return True

    @staticmethod
    def _fmmu_bits(f: _Fmmu, laddr: int, lend: int) -> list[tuple[int, int]]:
        """(logical bit, physical bit) pairs of a bit-wise FMMU inside the datagram's range."""
        first = f.lstart * 8 + f.lbit0
        last = (f.lend - 1) * 8 + f.lbit1
        lo = max(first, laddr * 8)
        hi = min(last, lend * 8 - 1)
        pbase = f.phys * 8 + f.pbit - first
        return [(b, b + pbase) for b in range(lo, hi + 1)]

    # ------------------------------------------------------------------ FMMU / SM caches
    def _rebuild_fmmus(self) -> None:
        out = []
        for i in range(self.n_fmmu):
            lstart, length, b0, b1, phys, pbit, ftype, act = FMMU_REG.unpack_from(self.mem, REG_FMMU + 16 * i)
            if act & 1 and length and ftype & 3:
                out.append(_Fmmu(lstart, length, b0 & 7, b1 & 7, phys, pbit & 7, ftype))
        self._fmmus = tuple(out)

    def _rebuild_sms(self, old: bytes, address: int, *, master: bool = True) -> None:
        """Recompute the SyncManagers the ESC runs after a write of their registers.

        An enabled SyncManager is activated only when its buffer starts in process RAM and does not
        overlap a lower activated SyncManager: registers and process RAM are separate (ET1100 data
        sheet II: 0x0000-0x0FFF registers, process RAM from 0x1000), so a buffer over the registers
        would let mailbox data overwrite AL status and friends (issue 21, defect 2). The master sees
        the refusal through the firmware (``EscApplication.sm_changed``: AL status code 0x0016 for
        the mailbox, 0x001D/0x001E for process data, as SOES does on its SM-change event); its
        next normal configuration of the SyncManager activates it again. ``master``: the write came
        from the master (the firmware is told); False for the PDI's own deactivation.
        """
        out: list[_Sm] = []
        mem = self.mem
        refused = 0
        for i in range(self.n_sm):
            base = REG_SM + 8 * i
            cfg = self.sm_config(i)
            o = base + 6 - address
            old_act = old[o] if 0 <= o < len(old) else mem[base + 6]
            runs = cfg.enabled and not mem[base + 7] & SM_PDI_DISABLE
            if runs and (cfg.start < RAM_START or any(s.start < cfg.start + cfg.length and cfg.start < s.end
                                                      for s in out)):
                runs = False
                refused += 1
            if not cfg.enabled or (not runs and not mem[base + 7] & SM_PDI_DISABLE):
                mem[base + 5] &= ~(SM_STATUS_FULL | SM_STATUS_WRITE_EVENT) & 0xFF
            elif runs and cfg.mailbox and not cfg.ecat_writes and (cfg.activate ^ old_act) & SM_ACT_REPEAT:
                self._mailbox_repeat(i, cfg)
            if runs:
                out.append(_Sm(cfg))
        self.stats.refused_sms += refused
        self._sms = tuple(out)
        self._active_sms = frozenset(s.index for s in out)
        if master:
            self.app.sm_changed()

    def _mailbox_repeat(self, index: int, cfg: SmConfig) -> None:
        """Repeat request toggled: put the last message back and acknowledge (ETG.1000.4 mailbox)."""
        base = REG_SM + 8 * index
        if self._mbx_last:
            self._store(cfg.start, self._mbx_last[:cfg.length].ljust(cfg.length, b"\0"))
            self.mem[base + 5] |= SM_STATUS_FULL
        self.mem[base + 7] = (self.mem[base + 7] & ~SM_PDI_REPEAT_ACK) | (cfg.activate & SM_ACT_REPEAT)

    # ------------------------------------------------------------------ AL state machine
    def _al_control(self, control: int) -> None:
        requested = control & 0x0F
        ack = bool(control & AL_ACK)
        status = self.al_status
        current = AlState(status & 0x0F)
        error = bool(status & AL_ERROR)
        try:
            target = AlState(requested)
        except ValueError:
            self._refuse(current, AlStatusCode.UNKNOWN_STATE)
            return
        if target == AlState.INIT:
            self._release_unused_sms()
        if error and not ack and _RANK[target] >= _RANK[current]:
            return  # an error indication is only left with an acknowledge (or by going down)
        if target == current:
            if ack:
                U16.pack_into(self.mem, REG_AL_STATUS, int(current))
                U16.pack_into(self.mem, REG_AL_STATUS_CODE, 0)
            return
        if (current, target) not in AL_TRANSITIONS:
            self._refuse(current, AlStatusCode.INVALID_STATE_CHANGE)
            return
        code = self.app.check_transition(current, target)
        if code:
            self._refuse(current, code)
            return
        U16.pack_into(self.mem, REG_AL_STATUS, int(target))
        U16.pack_into(self.mem, REG_AL_STATUS_CODE, 0)
        if target == AlState.OP:
            self._start_watchdog()
        else:
            self._stop_watchdog()
        if _RANK[target] < _RANK[current] and target == AlState.INIT:
            for i in range(self.n_sm):
                self.mem[REG_SM + 8 * i + 5] &= ~SM_STATUS_FULL & 0xFF
        self.app.state_changed(current, target, 0)

    def _release_unused_sms(self) -> None:
        """An INIT request: the firmware deactivates (PDI side) every SyncManager it does not serve.

        A master configures only the SyncManagers it uses (SOEM's config_init clears SM0-3 and FMMU0-2),
        so SM4+ left enabled by an earlier master, or by a storm of random frames, would otherwise
        overlap the mailbox forever; the firmware's own channels stay under the master's control.
        """
        mem = self.mem
        changed = False
        for i in range(self.firmware_sms, self.n_sm):
            at = REG_SM + 8 * i + 7
            if not mem[at] & SM_PDI_DISABLE:
                mem[at] |= SM_PDI_DISABLE
                changed = True
        if changed:
            self._rebuild_sms(bytes(mem[REG_SM:REG_SM + 8 * self.n_sm]), REG_SM, master=False)

    def _refuse(self, current: AlState, code: int) -> None:
        self.stats.al_refusals += 1
        U16.pack_into(self.mem, REG_AL_STATUS, int(current) | AL_ERROR)
        U16.pack_into(self.mem, REG_AL_STATUS_CODE, code)

    # ------------------------------------------------------------------ SM watchdog
    def watchdog_time(self) -> float:
        """SM watchdog time in seconds: (divider + 2) * 40 ns * time (ET1100 0x0400/0x0420); 0 = off."""
        div: int = U16.unpack_from(self.mem, REG_WD_DIVIDER)[0]
        ticks: int = U16.unpack_from(self.mem, REG_WD_TIME_SM)[0]
        return (div + 2) * 40e-9 * ticks

    def _start_watchdog(self) -> None:
        self._stop_watchdog()
        period = self.watchdog_time()
        if period <= 0 or not any(s.watchdog for s in self._sms):
            return
        self._wd_last = self.clock.now()
        self._wd_timer = self.clock.call_at(self._wd_last + period, self._wd_check)

    def _stop_watchdog(self) -> None:
        if self._wd_timer is not None:
            self._wd_timer.cancel()
            self._wd_timer = None

    def _wd_check(self) -> None:
        self._wd_timer = None
        period = self.watchdog_time()
        if period <= 0 or self.al_state != AlState.OP:
            return
        due = self._wd_last + period
        now = self.clock.now()
        if now < due:
            self._wd_timer = self.clock.call_at(due, self._wd_check)
            return
        self.stats.watchdog_expiries += 1
        self.mem[REG_WD_STATUS_SM] = 0
        self.mem[REG_WD_COUNTER_SM] = min(0xFF, self.mem[REG_WD_COUNTER_SM] + 1)
        self.force_state(AlState.SAFEOP, AlStatusCode.SM_WATCHDOG)

    # ------------------------------------------------------------------ SII EEPROM interface
    def _sii_config_bits(self) -> int:
        """0x0502 bits 5..7, fixed by the hardware: 8-byte reads, address bytes by EEPROM size."""
        return SII_READ8 | (SII_TWO_ADDRESS_BYTES if len(self.eeprom) > 2048 else 0)

    def _sii_command(self) -> None:
        mem = self.mem
        ctrl = U16.unpack_from(mem, REG_SII_CONTROL)[0]
        cmd = (ctrl >> 8) & 0x07
        # A master writes the whole word (KickCAT: 0x0100 for a read): the configuration bits stay what
        # the hardware says; errors, command and busy are cleared.
        status = self._sii_config_bits()
        if cmd == 0:
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
            if not self.reload_eeprom():
                status |= SII_ERR_CHECKSUM
        else:
            status |= SII_ERR_ACK
        U16.pack_into(mem, REG_SII_CONTROL, status)

    # ------------------------------------------------------------------ distributed clocks
    def _refresh_dc(self, address: int, end: int) -> None:
        if end > REG_DC_SYSTEM_TIME and address < REG_DC_SYSTEM_TIME + 8:
            U64.pack_into(self.mem, REG_DC_SYSTEM_TIME, self.system_time_ns())

    def _dc_write(self, address: int, end: int, old: bytes) -> None:
        mem = self.mem
        if address < REG_DC_RECV_TIME + 4 and end > REG_DC_RECV_TIME:
            # A write to port 0's receive time latches the receive times of all ports.
            t = self.local_time_ns()
            U32.pack_into(mem, REG_DC_RECV_TIME, t & 0xFFFFFFFF)
            t1 = t + 40 * self._downstream if self._downstream else 0
            U32.pack_into(mem, REG_DC_RECV_TIME + 4, t1 & 0xFFFFFFFF)
            U32.pack_into(mem, REG_DC_RECV_TIME + 8, 0)
            U32.pack_into(mem, REG_DC_RECV_TIME + 12, 0)
            U64.pack_into(mem, REG_DC_RECV_TIME_PU, t)
        if address < REG_DC_SYSTEM_TIME + 8 and end > REG_DC_SYSTEM_TIME:
            # Writes to the system time feed drift compensation; our local clocks do not drift.
            stop = min(end, REG_DC_SYSTEM_TIME + 8)
            lo = max(address, REG_DC_SYSTEM_TIME)
            mem[lo:stop] = old[lo - address:stop - address]
        if address <= REG_DC_ACTIVATION < end:
            self._sync0_configure()

    def _sync0_configure(self) -> None:
        if self._sync0_timer is not None:
            self._sync0_timer.cancel()
            self._sync0_timer = None
        act = self.mem[REG_DC_ACTIVATION]
        cycle_ns = U32.unpack_from(self.mem, REG_DC_SYNC0_CYCLE)[0]
        if not (act & 0x01 and act & 0x02) or cycle_ns == 0:
            return
        start_sys = U64.unpack_from(self.mem, REG_DC_START_TIME)[0]
        offset = U64.unpack_from(self.mem, REG_DC_SYSTEM_OFFSET)[0]
        start = ((start_sys - offset) & 0xFFFFFFFFFFFFFFFF) / 1e9
        cycle = max(cycle_ns, SYNC0_MIN_CYCLE_NS) / 1e9
        now = self.clock.now()
        if start < now:
            start += (int((now - start) / cycle) + 1) * cycle
        self._sync0_cycle = cycle
        self._sync0_next = start
        self._sync0_timer = self.clock.call_at(start, self._sync0_fire)

    def _sync0_fire(self) -> None:
        t = self._sync0_next
        nxt = t + self._sync0_cycle
        now = self.clock.now()
        if nxt <= now:  # pulses the PDI missed while it was busy merge into this one
            nxt += (int((now - nxt) / self._sync0_cycle) + 1) * self._sync0_cycle
        self._sync0_next = nxt
        self._sync0_timer = self.clock.call_at(self._sync0_next, self._sync0_fire)
        self.mem[REG_DC_SYNC0_STATUS] |= 0x01
        self.app.sync0(t)
