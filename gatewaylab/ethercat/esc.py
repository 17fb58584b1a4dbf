"""Emulated ET1100-class EtherCAT Slave Controller: the datagram engine over its parts, and the PDI events.

Sans-I/O: :meth:`Esc.process_datagram` works in place on a frame buffer (as the real ESC does on the
fly). Time comes from the injected clock (SM watchdog, DC system time, SYNC0). :class:`Esc` composes
one part per concept, each in its own module:

- :mod:`~gatewaylab.ethercat.esc_memory`: registers and process RAM, SyncManagers, FMMUs; the one way
  into ESC memory (``ecat_read`` / ``ecat_write``, as SOES's ESC_read / ESC_write);
- :mod:`~gatewaylab.ethercat.esc_al`: the AL state machine and the SM watchdog;
- :mod:`~gatewaylab.ethercat.esc_sii`: the EEPROM (SII) interface;
- :mod:`~gatewaylab.ethercat.esc_dc`: distributed clocks, SYNC0/SYNC1 (``Esc.sync0_period`` and
  friends are the one way a device reads the DC settings);
- :mod:`~gatewaylab.ethercat.esc_registers`: the register map; :mod:`~gatewaylab.ethercat.esc_events`:
  the PDI events.

Event contract (the seam between the ESC and the firmware behind it, as h11 pulls events out of its
core):

1. The ESC never calls the firmware while it accesses memory. What an access asks of the firmware is
   returned as PDI events, frozen records in the order they happened: a SyncManager buffer written
   (:class:`SmWritten`) or read (:class:`SmRead`), AL control written (:class:`AlControlRequested`),
   SyncManager registers written (:class:`SmChanged`).
2. An access is one read or one write of ESC memory. A physical or broadcast datagram is one access,
   or two for a read-write command (APRW, FPRW, BRW: a read, then a write of the data as it arrived);
   a logical datagram is one access per FMMU its range hits, every writing FMMU first (LWR, LRW: the
   frame's data as it arrived at this slave), then every reading one (LRD, LRW). When an access
   raised events, :meth:`Esc.process_datagram` returns them with the datagram paused after that
   access; the caller delivers them and calls :meth:`Esc.resume_datagram`, which runs the rest of
   the datagram and returns the events of its next access that raised any, or None once the
   datagram is complete. No events, no pause: process_datagram returns None for a complete datagram.
3. The working counter is written when the datagram completes; a datagram whose delivery raised
   (a defect of a device) keeps this slave's share uncounted.
4. So the firmware sees an access's events before the next access of the same datagram and before
   the next datagram of the frame reaches this ESC: an application that answers outputs with inputs
   on the SM2 write event is read back by the same LRW (``ethercat_io``'s loop-back), a 1-buffer
   SyncManager that two FMMUs write in one LRW (SOEM maps some layouts twice) takes both writes, and
   an AL status read after an AL control write in the same frame sees the answer. The AL request
   itself runs on the PDI side (:meth:`Esc.al_control`, from the delivery), as SOES's ESC_ALevent does.
5. Timers are not accesses: a SYNC0 pulse and an SM watchdog expiry reach the firmware from the clock
   (:class:`EscApplication`).

:meth:`gatewaylab.ethercat.slave.Slave.process_datagram` is the delivery loop; :class:`Segment` calls
it for each slave. Register map and bit meanings follow the ET1100 hardware data sheet; the state
machine follows IDX guide 4.2 (tables 4-16..4-18).
"""

from __future__ import annotations

from typing import Final, Protocol

from gatewaylab.common.clock import Clock
from gatewaylab.ethercat.esc_al import AlFirmware, AlStateMachine
from gatewaylab.ethercat.esc_dc import DistributedClocks
from gatewaylab.ethercat.esc_events import AlControlRequested, EscEvent, SmChanged, SmRead, SmWritten
from gatewaylab.ethercat.esc_memory import EscMemory, Fmmu
from gatewaylab.ethercat.esc_registers import (
    AL_ACK,
    AL_ERROR,
    AL_TRANSITIONS,
    DL_STATUS_PDI_OPERATIONAL,
    DL_STATUS_WD_OK,
    FMMU_REG,
    RAM_START,
    REG_AL_CONTROL,
    REG_AL_STATUS,
    REG_AL_STATUS_CODE,
    REG_DC_ACTIVATION,
    REG_DC_RECV_TIME,
    REG_DC_RECV_TIME_PU,
    REG_DC_START_TIME,
    REG_DC_SYNC0_CYCLE,
    REG_DC_SYNC0_STATUS,
    REG_DC_SYNC1_CYCLE,
    REG_DC_SYSTEM_DELAY,
    REG_DC_SYSTEM_OFFSET,
    REG_DC_SYSTEM_TIME,
    REG_DL_CONTROL,
    REG_DL_STATUS,
    REG_FEATURES,
    REG_FMMU,
    REG_PDI_CONTROL,
    REG_RX_ERROR,
    REG_SII_ADDRESS,
    REG_SII_CONFIG,
    REG_SII_CONTROL,
    REG_SII_DATA,
    REG_SM,
    REG_STATION_ADDRESS,
    REG_STATION_ALIAS,
    REG_TYPE,
    REG_WD_COUNTER_SM,
    REG_WD_DIVIDER,
    REG_WD_STATUS_SM,
    REG_WD_TIME_PDI,
    REG_WD_TIME_SM,
    SII_BUSY,
    SII_ERR_ACK,
    SII_ERR_CHECKSUM,
    SII_ERR_WRITE_ENABLE,
    SII_READ8,
    SII_TWO_ADDRESS_BYTES,
    SM_ACT_ENABLE,
    SM_ACT_REPEAT,
    SM_CTRL_ECAT_WRITE,
    SM_CTRL_MAILBOX,
    SM_CTRL_WATCHDOG,
    SM_PDI_DISABLE,
    SM_PDI_REPEAT_ACK,
    SM_REG,
    SM_STATUS_FULL,
    SM_STATUS_READ_EVENT,
    SM_STATUS_WRITE_EVENT,
    SYNC0_MIN_CYCLE_NS,
    U8,
    U16,
    U32,
    U64,
    AlState,
    EscStats,
    SmConfig,
)
from gatewaylab.ethercat.esc_sii import SiiInterface, sii_checksum

__all__ = [
    "AL_ACK", "AL_ERROR", "AL_TRANSITIONS", "DL_STATUS_PDI_OPERATIONAL", "DL_STATUS_WD_OK", "FMMU_REG",
    "RAM_START", "REG_AL_CONTROL", "REG_AL_STATUS", "REG_AL_STATUS_CODE", "REG_DC_ACTIVATION",
    "REG_DC_RECV_TIME", "REG_DC_RECV_TIME_PU", "REG_DC_START_TIME", "REG_DC_SYNC0_CYCLE",
    "REG_DC_SYNC0_STATUS", "REG_DC_SYNC1_CYCLE", "REG_DC_SYSTEM_DELAY", "REG_DC_SYSTEM_OFFSET",
    "REG_DC_SYSTEM_TIME", "REG_DL_CONTROL", "REG_DL_STATUS", "REG_FEATURES", "REG_FMMU", "REG_PDI_CONTROL",
    "REG_RX_ERROR", "REG_SII_ADDRESS", "REG_SII_CONFIG", "REG_SII_CONTROL", "REG_SII_DATA", "REG_SM",
    "REG_STATION_ADDRESS", "REG_STATION_ALIAS", "REG_TYPE", "REG_WD_COUNTER_SM", "REG_WD_DIVIDER",
    "REG_WD_STATUS_SM", "REG_WD_TIME_PDI", "REG_WD_TIME_SM", "SII_BUSY", "SII_ERR_ACK", "SII_ERR_CHECKSUM",
    "SII_ERR_WRITE_ENABLE", "SII_READ8", "SII_TWO_ADDRESS_BYTES", "SM_ACT_ENABLE", "SM_ACT_REPEAT",
    "SM_CTRL_ECAT_WRITE", "SM_CTRL_MAILBOX", "SM_CTRL_WATCHDOG", "SM_PDI_DISABLE", "SM_PDI_REPEAT_ACK",
    "SM_REG", "SM_STATUS_FULL", "SM_STATUS_READ_EVENT", "SM_STATUS_WRITE_EVENT", "SYNC0_MIN_CYCLE_NS", "U8",
    "U16", "U32", "U64", "AlControlRequested", "AlState", "Esc", "EscApplication", "EscEvent", "EscStats",
    "SmChanged", "SmConfig", "SmRead", "SmWritten", "sii_checksum",
]

# Commands by number (datagram.Command), inlined on the hot path.
_APRD: Final = 1
_APWR: Final = 2
_APRW: Final = 3
_FPRD: Final = 4
_FPWR: Final = 5
_FPRW: Final = 6
_BRD: Final = 7
_BWR: Final = 8
_BRW: Final = 9
_LRD: Final = 10
_LWR: Final = 11
_LRW: Final = 12
_ARMW: Final = 13
_FRMW: Final = 14
# What resume_datagram does next: nothing pending, write the working counter, the write half of a
# read-write command (the data as it arrived), the writing FMMUs of a logical datagram, its reading ones.
_IDLE: Final = 0
_FINISH: Final = 1
_WRITE_BACK: Final = 2
_WRITES: Final = 3
_READS: Final = 4
_NO_BUF: Final = bytearray()


def _le16(buf: bytearray, at: int) -> int:
    """A little-endian 16-bit field of a frame (byte indexing: compiled, no struct tuple per field)."""
    return buf[at] | buf[at + 1] << 8


def _put_le16(buf: bytearray, at: int, value: int) -> None:
    """Store ``value`` modulo 2**16 as a little-endian 16-bit field (the working counter wraps)."""
    buf[at] = value & 0xFF
    buf[at + 1] = (value >> 8) & 0xFF


class EscApplication(AlFirmware, Protocol):
    """What the ESC asks of the slave behind it outside the events: the AL state machine's
    questions (:class:`AlFirmware`) and the SYNC0 pulses (the real ESC raises the SYNC0 line)."""

    def sync0(self, t: float) -> None:
        """A SYNC0 pulse at clock time ``t``."""
        ...


class Esc:
    """One slave controller. ``app`` is the firmware behind it; ``eeprom`` is the SII image."""

    def __init__(self, clock: Clock, eeprom: bytes, app: EscApplication, *, ram_size: int = 0x2000,
                 fmmus: int = 16, sms: int = 16, dc: bool = True, eeprom_size: int | None = None,
                 firmware_sms: int = 4, output_sm: int = 2) -> None:
        self.clock = clock
        self.app = app
        self.stats = EscStats()
        #: Registers (0x0000-0x0FFF) and process RAM, shared by every part.
        self.mem = bytearray(RAM_START + ram_size)
        #: The device has distributed clocks (feature register 0x0008).
        self.dc = dc
        self.sii = SiiInterface(self.mem, self.stats, eeprom, eeprom_size)
        self.clocks = DistributedClocks(clock, self.mem, app.sync0)
        self.memory = EscMemory(clock, self.mem, self.stats, self.sii, self.clocks, fmmus=fmmus, sms=sms,
                                firmware_sms=firmware_sms, output_sm=output_sm)
        self.al = AlStateMachine(clock, self.memory, app)
        self.n_fmmu = fmmus
        self.n_sm = sms
        #: Powered off / link down (a device resetting itself): datagrams pass untouched, as if the
        #: slave were not in the line (see :meth:`power_cycle`).
        self.offline = False
        self._step = _IDLE
        self._buf = _NO_BUF
        self._off = self._dlen = self._addr = self._inc = self._cmd = self._fi = 0
        self._fmmus: tuple[Fmmu, ...] = ()
        self._incoming = b""
        self._reset_registers()

    def _reset_registers(self) -> None:
        self.memory.reset(self.dc)
        self.al.reset()
        self.sii.reset()
        self.memory.update_dl_status(self.clocks.downstream)

    # ------------------------------------------------------------------ line and power
    def set_downstream(self, count: int, links: int = -1) -> None:
        """How many slaves follow this one in the line (DC delays) and, when given, which ports have a link
        (bit p: port p; DL status 0x0110, kept across power cycles; -1: port 0, and port 1 when slaves follow)."""
        self.clocks.downstream = count
        self.memory.update_dl_status(count, links)

    def power_cycle(self) -> None:
        """Power-on reset (a device restarting after a firmware update): registers and process RAM
        cleared (station address, SyncManagers, FMMUs, DC lost), timers stopped, SII reloaded, INIT."""
        old = self.al_state
        self.al.stop_watchdog()
        self.clocks.stop()
        self.clocks.local.reset_loop()
        self.mem[:] = bytes(len(self.mem))
        self._step = _IDLE
        self._reset_registers()
        if old != AlState.INIT:
            self.app.state_changed(old, AlState.INIT, 0)

    # ------------------------------------------------------------------ state the firmware reads
    @property
    def eeprom(self) -> bytearray:
        """The SII EEPROM contents."""
        return self.sii.eeprom

    @property
    def pdi_outputs(self) -> dict[int, bytes]:
        """The newest complete buffer of every SyncManager the master writes."""
        return self.memory.pdi_outputs

    @property
    def station_address(self) -> int:
        """Configured station address (0x0010), the FPxx address of this slave."""
        return int(U16.unpack_from(self.mem, REG_STATION_ADDRESS)[0])

    @property
    def al_status(self) -> int:
        """AL status (0x0130): state in bits 3..0, error indication in bit 4."""
        return self.al.status

    @property
    def al_state(self) -> AlState:
        """The present AL state."""
        return self.al.state

    @property
    def al_status_code(self) -> int:
        """AL status code (0x0134)."""
        return self.al.status_code

    def sm_config(self, index: int) -> SmConfig:
        """SyncManager ``index`` as its registers say (whether the ESC runs it or not)."""
        return self.memory.sm_config(index)

    def sm_in_use(self, index: int) -> bool:
        """Enabled by the master and not deactivated by the PDI (0x0807 + 8n bit 0)."""
        return self.sm_config(index).enabled and not self.mem[REG_SM + 8 * index + 7] & SM_PDI_DISABLE

    def sm_active(self, index: int) -> bool:
        """The ESC runs this SyncManager: enabled by the master, not deactivated by the PDI, its
        buffer in process RAM (or an output one on 0x0F00:0x0F03) and clear of every lower SyncManager
        (``EscMemory.rebuild_sms``)."""
        return index in self.memory.active_sms

    @property
    def outputs_stopped(self) -> bool:
        """The firmware deactivated the output SyncManager on leaving OP by itself (SM watchdog, a
        device error); the master's next state change activates it again."""
        return self.memory.outputs_stopped

    def sm_status(self, index: int) -> int:
        """SyncManager status register (0x0805 + 8n): buffer full, write / read events."""
        return self.mem[REG_SM + 8 * index + 5]

    def fmmu_config(self, index: int) -> tuple[int, int, int, int, int, int, int, int]:
        """(logical start, length, start bit, stop bit, physical start, physical bit, type, active)."""
        v = FMMU_REG.unpack_from(self.mem, REG_FMMU + 16 * index)
        return (v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7])

    def watchdog_time(self) -> float:
        """SM watchdog time in seconds (0 = off)."""
        return self.al.watchdog_time()

    # ------------------------------------------------------------------ distributed clocks
    def local_time_ns(self) -> int:
        """The ESC's local clock in nanoseconds."""
        return self.clocks.local_time_ns()

    def system_time_ns(self) -> int:
        """DC system time: local time plus the master's offset (0x0920)."""
        return self.clocks.system_time_ns()

    @property
    def sync0_active(self) -> bool:
        """The master activated SYNC0 (0x0981: cyclic unit and SYNC0 generation)."""
        return self.clocks.sync0_active

    @property
    def sync0_cycle_ns(self) -> int:
        """SYNC0 cycle time as the master wrote it (0x09A0), in ns."""
        return self.clocks.sync0_cycle_ns

    @property
    def sync0_period(self) -> float:
        """The period the SYNC0 pulses come at, in seconds; 0.0 while SYNC0 is off."""
        return self.clocks.sync0_period

    @property
    def sync0_start_time_ns(self) -> int:
        """Start of the SYNC0 train in DC system time (0x0990), in ns."""
        return self.clocks.sync0_start_time_ns

    @property
    def sync0_next(self) -> float:
        """Clock time of the next SYNC0 pulse (while pulses run)."""
        return self.clocks.sync0_next

    @property
    def sync1_active(self) -> bool:
        """The master activated SYNC1 (0x0981: cyclic unit and SYNC1 generation)."""
        return self.clocks.sync1_active

    @property
    def sync1_cycle_ns(self) -> int:
        """SYNC1 cycle time as the master wrote it (0x09A4), in ns."""
        return self.clocks.sync1_cycle_ns

    # ------------------------------------------------------------------ PDI side (the slave application)
    def reload_eeprom(self) -> bool:
        """Load the SII configuration area (words 0..7); False and no load on a bad checksum."""
        return self.sii.reload()

    def pdi_write(self, address: int, data: bytes | bytearray) -> None:
        """The application writes process RAM (inputs buffer); no ECAT-side effects."""
        self.memory.store(address, data)

    def pdi_read(self, address: int, length: int) -> bytes:
        """The application reads process RAM (what the master wrote)."""
        return bytes(self.mem[address:address + length])

    def mailbox_put(self, sm_index: int, message: bytes) -> bool:
        """Put a message into the (empty) slave-to-master mailbox; False when it is still full or the
        ESC does not run that SyncManager (e.g. a master placed it over the registers)."""
        return self.memory.mailbox_put(sm_index, message)

    def sm_set_full(self, sm_index: int) -> None:
        """The PDI filled a 1-buffer SM (inputs written for the master to read)."""
        self.mem[REG_SM + 8 * sm_index + 5] |= SM_STATUS_FULL

    def mailbox_full(self, sm_index: int) -> bool:
        """The 1-buffer SyncManager holds a message not yet taken."""
        return bool(self.mem[REG_SM + 8 * sm_index + 5] & SM_STATUS_FULL)

    def mailbox_clear(self, sm_index: int) -> None:
        """The PDI took the buffer of a 1-buffer SyncManager: the master may write the next one."""
        self.mem[REG_SM + 8 * sm_index + 5] &= ~SM_STATUS_FULL & 0xFF

    def al_control(self, control: int) -> None:
        """Serve an AL control request (delivered from :class:`AlControlRequested`)."""
        self.al.control(control)

    def force_state(self, state: AlState, code: int = 0) -> None:
        """The application changes state by itself (error: SAFEOP + error flag + code)."""
        self.al.force(state, code)

    # ------------------------------------------------------------------ ECAT side
    def ecat_read(self, address: int, length: int) -> bytes | None:
        """A master read outside a datagram; None when refused. Its events wait in
        :meth:`take_events`."""
        return self.memory.ecat_read(address, length)

    def ecat_write(self, address: int, data: bytes | bytearray | memoryview) -> bool:
        """A master write outside a datagram; False when refused. Its events wait in
        :meth:`take_events`."""
        return self.memory.ecat_write(address, data)

    def take_events(self) -> list[EscEvent]:
        """The PDI events raised since they were last taken (in order), handed over once."""
        events = self.memory.events
        self.memory.events = []
        return events

    def process_datagram(self, buf: bytearray, pos: int, cmd: int, dlen: int) -> list[EscEvent] | None:
        """Execute one datagram of a frame in place (auto-increment address, data, working counter).

        Returns the PDI events of its first access that raised any, the datagram paused after that
        access (call :meth:`resume_datagram` once they are delivered), or None: the datagram is
        complete (see the module docstring)."""
        self.stats.datagrams += 1
        memory = self.memory
        if memory.events:
            memory.events = []  # left by an ecat_read/write outside a datagram, or a delivery that raised
        self._step = _IDLE
        if cmd == 0 or cmd > _FRMW or self.offline:
            return None  # NOP (and anything unknown) passes untouched; so does everything while offline
        off = pos + 10
        inc = 0
        step = _FINISH
        if cmd >= _LRD and cmd <= _LRW:
            if not memory.fmmus:
                return None
            self._buf = buf
            self._off = off
            self._dlen = dlen
            self._addr = buf[pos + 2] | buf[pos + 3] << 8 | buf[pos + 4] << 16 | buf[pos + 5] << 24
            self._cmd = cmd
            self._fi = -1
            self._inc = 0
            self._step = _READS if cmd == _LRD else _WRITES
            return self.resume_datagram()
        else:
            broadcast = _BRD <= cmd <= _BRW
            if cmd <= _APRW or cmd == _ARMW or broadcast:
                adp = _le16(buf, pos + 2)
                _put_le16(buf, pos + 2, adp + 1)
                addressed = adp == 0 or broadcast
            else:
                adp = _le16(buf, pos + 2)
                mem = self.mem
                addressed = adp == _le16(mem, REG_STATION_ADDRESS) or (
                    bool(mem[REG_DL_CONTROL + 3] & 0x01) and adp == _le16(mem, REG_STATION_ALIAS))
            ado = _le16(buf, pos + 4)
            if cmd >= _ARMW:
                inc = self._read(buf, off, ado, dlen) if addressed else self._write(ado, bytes(buf[off:off + dlen]))
            elif addressed:
                inc, step = self._physical(buf, off, ado, dlen, cmd)
        if step == _FINISH and not memory.events:
            if inc:
                wkc_at = off + dlen
                _put_le16(buf, wkc_at, _le16(buf, wkc_at) + inc)
            return None
        self._buf = buf
        self._off = off
        self._dlen = dlen
        self._inc = inc
        self._step = step
        events = memory.events
        if events:
            memory.events = []
            return events
        return self.resume_datagram()

    def resume_datagram(self) -> list[EscEvent] | None:
        """Continue a paused datagram: the events of its next access that raised any, or None once it
        is complete (working counter written).

        A logical datagram runs here from its start: one access per FMMU its range hits, every
        writing FMMU first (the frame's data as it arrived at this slave), then every reading one.
        WKC: read 1, write 1 (LWR) or 2 (LRW), each counted once."""
        step = self._step
        memory = self.memory
        if step >= _WRITES:
            fmmus = memory.fmmus if self._fi < 0 else self._fmmus
            buf, off, laddr = self._buf, self._off, self._addr
            lend = laddr + self._dlen
            n = len(fmmus)
            i = self._fi
            if i < 0:  # the first call, from process_datagram
                self._fmmus = fmmus
                i = 0
            if step == _WRITES:
                lrw = self._cmd == _LRW
                while i < n:
                    f = fmmus[i]
                    i += 1
                    if f.write and f.lstart < lend and laddr < f.lend and memory.fmmu_write(f, buf, off, laddr, lend):
                        self._inc |= 2 if lrw else 1
                        events = memory.events
                        if events:
                            memory.events = []
                            self._fi = i
                            if i == n and not lrw:
                                self._step = _FINISH
                            return events
                if not lrw:
                    self._finish()
                    return None
                self._step = _READS
                i = 0
            while i < n:
                f = fmmus[i]
                i += 1
                if f.read and f.lstart < lend and laddr < f.lend and memory.fmmu_read(f, buf, off, laddr, lend):
                    self._inc |= 1
                    events = memory.events
                    if events:
                        memory.events = []
                        self._fi = i
                        if i == n:
                            self._step = _FINISH
                        return events
        elif step == _WRITE_BACK:
            self._step = _FINISH
            if memory.ecat_write(self._addr, self._incoming):
                self._inc += 2
            events = memory.events
            if events:
                memory.events = []
                return events
        elif step != _FINISH:
            return None
        inc = self._inc  # _finish(), inlined: the last call of every datagram that raised events
        if inc:
            buf = self._buf
            wkc_at = self._off + self._dlen
            _put_le16(buf, wkc_at, _le16(buf, wkc_at) + inc)
        self._buf = _NO_BUF
        self._step = _IDLE
        return None

    def lose_datagram(self) -> None:
        """Fault injection, from the delivery of a paused datagram's events: the access happened in the
        ESC (a mailbox read emptied the buffer) but the master gets nothing of it -- the datagram keeps
        the working counter it arrived with and its data is cleared, as for a reply lost on its way."""
        step = self._step
        if step != _IDLE:
            self._inc = 0
            if step < _WRITES:  # a physical datagram is this slave's alone; a logical one carries others' data
                self._buf[self._off:self._off + self._dlen] = bytes(self._dlen)

    def _finish(self) -> None:
        """The datagram is complete: add this slave's share to the working counter."""
        inc = self._inc
        if inc:
            buf = self._buf
            wkc_at = self._off + self._dlen
            _put_le16(buf, wkc_at, _le16(buf, wkc_at) + inc)
        self._buf = _NO_BUF
        self._fmmus = ()
        self._step = _IDLE

    def _physical(self, buf: bytearray, off: int, ado: int, dlen: int, cmd: int) -> tuple[int, int]:
        """The first access of an addressed physical or broadcast datagram: (WKC so far, next step)."""
        kind = (cmd - 1) % 3  # 0 read, 1 write, 2 read-write (APxx, FPxx and Bxx share the pattern)
        if kind == 1:
            return self._write(ado, bytes(buf[off:off + dlen])), _FINISH
        if kind == 2:
            self._incoming = bytes(buf[off:off + dlen])
            self._addr = ado
        data = self.memory.ecat_read(ado, dlen)
        inc = 0
        if data is not None:
            if cmd >= _BRD:  # a broadcast read ORs every slave's data into the frame
                buf[off:off + dlen] = bytes(a | b for a, b in zip(buf[off:off + dlen], data, strict=True))
            else:
                buf[off:off + dlen] = data
            inc = 1
        return inc, (_WRITE_BACK if kind == 2 else _FINISH)

    def _read(self, buf: bytearray, off: int, ado: int, dlen: int) -> int:
        data = self.memory.ecat_read(ado, dlen)
        if data is None:
            return 0
        buf[off:off + dlen] = data
        return 1

    def _write(self, ado: int, data: bytes) -> int:
        return 1 if self.memory.ecat_write(ado, data) else 0
