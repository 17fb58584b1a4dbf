"""ESC memory: the register file and process RAM, SyncManagers and FMMUs, the one way into them.

Every master access goes through :meth:`EscMemory.ecat_read` / :meth:`EscMemory.ecat_write` (as
every firmware access goes through SOES's ESC_read / ESC_write): read-only registers keep their
values, a write to a register with a meaning hands it to its unit (SII command, FMMU and SyncManager
configuration, distributed clocks), SyncManagers guard their buffers (a full mailbox refuses a write,
an empty one a read) and hand completed buffers over. What the firmware must react to is appended to
:attr:`EscMemory.events` as a PDI event (:mod:`gatewaylab.ethercat.esc_events`), never called: the
ESC returns those after the access. FMMUs map logical datagrams onto the same two accesses, bit-wise
ones included. Register map: ET1100 data sheet section II; SyncManagers ETG.1000.4.
"""

from __future__ import annotations

from collections.abc import Callable

from gatewaylab.common.clock import Clock
from gatewaylab.ethercat.esc_dc import DistributedClocks
from gatewaylab.ethercat.esc_events import SM_CHANGED, AlControlRequested, EscEvent, SmRead, SmWritten
from gatewaylab.ethercat.esc_registers import (
    FMMU_REG,
    RAM_START,
    REG_AL_CONTROL,
    REG_DC_SYNC0_STATUS,
    REG_DIGITAL_OUT,
    REG_DIGITAL_OUT_END,
    REG_DL_CONTROL,
    REG_DL_STATUS,
    REG_FEATURES,
    REG_FMMU,
    REG_SII_CONTROL,
    REG_SM,
    REG_TYPE,
    REG_WD_DIVIDER,
    REG_WD_STATUS_SM,
    REG_WD_TIME_SM,
    SM_ACT_REPEAT,
    SM_CTRL_WATCHDOG,
    SM_PDI_DISABLE,
    SM_PDI_REPEAT_ACK,
    SM_REG,
    SM_STATUS_FULL,
    SM_STATUS_WRITE_EVENT,
    U16,
    U32,
    EscStats,
    SmConfig,
)
from gatewaylab.ethercat.esc_sii import SiiInterface

__all__ = ["READ_ONLY", "EscMemory", "Fmmu"]


#: ECAT-side read-only registers (ET1100 data sheet section II, "ECAT r/-"): information, DL status,
#: AL status and code, PDI control/configuration, AL event mask and request, EEPROM PDI access state,
#: watchdog status, DC receive time of the processing unit, SYNC status.
READ_ONLY = ((0x0000, 0x0010), (0x0110, 0x0112), (0x0130, 0x0138), (0x0140, 0x0142), (0x0150, 0x0154),
             (0x0204, 0x0208), (0x0210, 0x0214), (0x0220, 0x0228), (0x0501, 0x0502), (0x0440, 0x0444),
             (0x0918, 0x0920), (REG_DC_SYNC0_STATUS, REG_DC_SYNC0_STATUS + 2))


class _Sm:
    """A SyncManager the ESC runs, decoded once per configuration write for the frame path."""

    __slots__ = ("ecat_writes", "end", "index", "mailbox", "read_event", "start", "status_addr", "watchdog",
                 "write_event")

    def __init__(self, cfg: SmConfig) -> None:
        self.index = cfg.index
        self.read_event = SmRead(cfg.index)
        self.write_event = SmWritten(cfg.index)
        self.start = cfg.start
        self.end = cfg.start + cfg.length
        self.mailbox = cfg.mailbox
        self.ecat_writes = cfg.ecat_writes
        self.watchdog = bool(cfg.control & SM_CTRL_WATCHDOG)
        self.status_addr = REG_SM + 8 * cfg.index + 5


class Fmmu:
    """An active FMMU, decoded once per configuration write for the frame path (0x0600 + 16n)."""

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


class EscMemory:
    """Registers + process RAM of one ESC, with its SyncManagers and FMMUs."""

    __slots__ = ("_memlen", "_sms", "active_sms", "clock", "dc", "events", "firmware_sms", "fmmus", "io_sms",
                 "links", "locked", "mbx_last", "mem", "n_fmmu", "n_sm", "output_sm", "outputs_stopped", "pdi_outputs",
                 "ro", "sii", "stats", "wd_changed", "wd_last")

    def __init__(self, clock: Clock, mem: bytearray, stats: EscStats, sii: SiiInterface, dc: DistributedClocks,
                 *, fmmus: int, sms: int, firmware_sms: int, output_sm: int = 2) -> None:
        self.clock = clock
        self.mem = mem
        self._memlen = len(mem)
        self.stats = stats
        self.sii = sii
        self.dc = dc
        self.n_fmmu = fmmus
        self.n_sm = sms
        #: SyncManagers the slave firmware serves (mailbox 0/1, process data 2/3); the others are
        #: deactivated from the PDI side on every INIT request (see ``release_unused_sms``).
        self.firmware_sms = min(firmware_sms, sms)
        #: The process data SyncManager the master writes (outputs; -1: none): the one the firmware
        #: deactivates when it leaves OP by itself (see :meth:`stop_outputs`).
        self.output_sm = output_sm
        #: The firmware deactivated the output SyncManager (a local exit from OP) and has not yet
        #: activated it again.
        self.outputs_stopped = False
        #: Buffers of SyncManagers the master enabled and the PDI deactivated: [start, end) pairs whose
        #: memory the ESC locks (see :meth:`rebuild_sms`); empty on the usual path.
        self.locked: tuple[tuple[int, int], ...] = ()
        #: 1: the master may not write this register byte (ECAT r/-).
        self.ro = bytearray(RAM_START)
        #: The active FMMUs, in register order (a logical datagram runs them one access each).
        self.fmmus: tuple[Fmmu, ...] = ()
        self._sms: tuple[_Sm, ...] = ()
        #: Output SyncManagers the ESC runs on the Digital I/O Output Data register 0x0F00:0x0F03 (an
        #: EL2008's): apart from ``_sms`` so that an access to process RAM never looks at them; empty
        #: on every slave whose SyncManagers all lie in process RAM.
        self.io_sms: tuple[_Sm, ...] = ()
        #: SyncManagers the ESC runs (see :meth:`sm_active`).
        self.active_sms: frozenset[int] = frozenset()
        #: The last message put into the slave-to-master mailbox (served again on a repeat request).
        self.mbx_last = b""
        #: The newest complete buffer of every SyncManager the master writes.
        self.pdi_outputs: dict[int, bytes] = {}
        #: Clock time of the last write to a SyncManager with the watchdog enabled.
        self.wd_last = 0.0
        #: told when the master writes the watchdog divider (0x0400) or time (0x0420) (the AL state machine)
        self.wd_changed: Callable[[], None] | None = None
        #: PDI events raised by the accesses since the ESC last handed them over.
        self.events: list[EscEvent] = []
        #: The ports with a physical link (bit p: port p), as the segment last set them; -1: not set (port 0,
        #: and port 1 when slaves follow).
        self.links = -1

    # ------------------------------------------------------------------ power-on
    def reset(self, dc: bool) -> None:
        """Power-on values of the information and DL registers; SyncManagers and FMMUs off."""
        m = self.mem
        self.fmmus = ()
        self._sms = ()
        self.io_sms = ()
        self.active_sms = frozenset()
        self.locked = ()
        self.outputs_stopped = False
        self.pdi_outputs.clear()
        self.mbx_last = b""
        self.events.clear()
        m[REG_TYPE] = 0x11  # ET1100
        m[0x0001] = 0x00
        U16.pack_into(m, 0x0002, 0x0002)
        m[0x0004] = self.n_fmmu
        m[0x0005] = self.n_sm
        m[0x0006] = (self._memlen - RAM_START) // 1024
        m[0x0007] = 0x0F  # ports 0 and 1 MII
        U16.pack_into(m, REG_FEATURES, 0x000C if dc else 0x0000)  # DC + 64-bit DC
        U32.pack_into(m, REG_DL_CONTROL, 0x00000001)
        for lo, hi in READ_ONLY:
            self.ro[lo:hi] = b"\x01" * (hi - lo)
        for i in range(self.n_sm):
            self.ro[REG_SM + 8 * i + 5] = 1
            self.ro[REG_SM + 8 * i + 7] = 1

    def update_dl_status(self, downstream: int, links: int = -1) -> None:
        """DL status 0x0110 (ET1100 data sheet, register 0x0110): bits 4-7 physical link on port 0-3; per port p
        bit 8+2p loop closed and bit 9+2p communication established. A port with a link is open with
        communication, one without is closed (auto close); ports 2 and 3 are not implemented (register 0x0007) and
        show nothing. ``links``: the ports with
        a link (bit p: port p), kept for later updates; -1 keeps the last, else port 0 and port 1 when slaves
        follow."""
        if links >= 0:
            self.links = links
        ports = self.links if self.links >= 0 else (0b11 if downstream else 0b01)
        status = U16.unpack_from(self.mem, REG_DL_STATUS)[0] & 0x0003
        for p in range(2):
            status |= ((0x0010 << p) | (0x0200 << 2 * p)) if ports >> p & 1 else 0x0100 << 2 * p
        U16.pack_into(self.mem, REG_DL_STATUS, status)

    # ------------------------------------------------------------------ SyncManager / FMMU state
    def sm_config(self, index: int) -> SmConfig:
        """SyncManager ``index`` as its registers say (whether the ESC runs it or not)."""
        start, length, control, _status, activate, _pdi = SM_REG.unpack_from(self.mem, REG_SM + 8 * index)
        return SmConfig(index, start, length, control, activate)

    def any_watchdog(self) -> bool:
        """A running SyncManager has its watchdog enabled (0x0804 bit 6): the SM watchdog may run."""
        return any(s.watchdog for s in self._sms) or any(s.watchdog for s in self.io_sms)

    # ------------------------------------------------------------------ PDI side
    def store(self, address: int, data: bytes | bytearray) -> None:
        """Write process RAM without ever growing it or reaching the registers: bytes past the end
        of process RAM are dropped (a SyncManager a master placed there has no memory behind it),
        bytes below 0x1000 too (registers and process RAM are separate, ET1100 data sheet II)."""
        if address < RAM_START:
            data = data[RAM_START - address:]
            address = RAM_START
        end = min(address + len(data), self._memlen)
        if address < end:
            self.mem[address:end] = data[:end - address]

    def mailbox_put(self, sm_index: int, message: bytes) -> bool:
        """Put a message into the (empty) slave-to-master mailbox; False when it is still full or the
        ESC does not run that SyncManager (e.g. a master placed it over the registers)."""
        cfg = self.sm_config(sm_index)
        status_addr = REG_SM + 8 * sm_index + 5
        if self.mem[status_addr] & SM_STATUS_FULL or sm_index not in self.active_sms:
            return False
        buf = message[:cfg.length].ljust(cfg.length, b"\x00")
        self.store(cfg.start, buf)
        self.mem[status_addr] |= SM_STATUS_FULL
        self.mbx_last = buf
        return True

    # ------------------------------------------------------------------ ECAT side: the one way in
    def ecat_read(self, address: int, length: int) -> bytes | None:
        """A master read; None when the ESC refuses it (empty mailbox): no WKC increment."""
        end = address + length
        mem = self.mem
        if address < RAM_START:
            if end > 0x0900 and address < 0x09A0:
                self.dc.refresh(address, end)
            if self.locked and end > REG_DIGITAL_OUT and address < REG_DIGITAL_OUT_END and \
                    self._locked(address, end):
                return None
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
        if hit is None and self.locked and self._locked(address, end):
            return None
        data = bytes(mem[address:end]) if end <= self._memlen else \
            bytes(mem[address:self._memlen]).ljust(length, b"\x00")
        if hit is not None:
            for sm in hit:
                if not sm.ecat_writes and end >= sm.end:
                    if sm.mailbox:  # 1-buffer mode: the buffer is free again
                        mem[sm.status_addr] &= ~SM_STATUS_FULL & 0xFF
                    self.events.append(sm.read_event)
        return data

    def ecat_write(self, address: int, data: bytes | bytearray | memoryview) -> bool:
        """A master write; False when refused (full mailbox): no WKC increment."""
        length = len(data)
        end = address + length
        mem = self.mem
        if address < RAM_START:
            if end > REG_DIGITAL_OUT and address < REG_DIGITAL_OUT_END and (self.io_sms or self.locked):
                if not self._output_register_write(address, end, data):
                    return False
            else:
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
        if hit is None and self.locked and self._locked(address, end):
            return False
        if end > self._memlen:
            data = bytes(data[:max(0, self._memlen - address)])
            end = self._memlen
        mem[address:end] = data
        if hit is not None:
            for sm in hit:
                if sm.ecat_writes and end >= sm.end:
                    self._buffer_written(sm)
        return True

    def _buffer_written(self, sm: _Sm) -> None:
        """The master completed ``sm``'s buffer: 1-buffer mode marks it full until the PDI reads it,
        3-buffer mode hands the PDI the newest complete buffer; the SM watchdog is triggered and the
        firmware gets the write event."""
        mem = self.mem
        mem[sm.status_addr] |= SM_STATUS_FULL if sm.mailbox else SM_STATUS_WRITE_EVENT
        self.pdi_outputs[sm.index] = bytes(mem[sm.start:sm.end])
        if sm.watchdog:
            self.wd_last = self.clock.now()
            mem[REG_WD_STATUS_SM] = 1
        self.events.append(sm.write_event)

    def _output_register_write(self, address: int, end: int, data: bytes | bytearray | memoryview) -> bool:
        """A master write over the Digital I/O Output Data register while an output SyncManager runs or is
        locked there: a complete buffer raises the same events as one in process RAM (write event in the
        SM status, the newest buffer for the PDI, the SM watchdog triggered); a locked buffer refuses the
        write. False: refused."""
        hit = [sm for sm in self.io_sms if sm.start < end and address < sm.end]
        if not hit and self.locked and self._locked(address, end):
            return False
        self._register_write(address, end, data)
        for sm in hit:
            if end >= sm.end:
                self._buffer_written(sm)     # a buffered SyncManager: the write event
        return True

    def watchdog_expired(self) -> None:
        """The SM watchdog expired: the digital outputs the ESC drives from 0x0F00 go to 0 (ET1100 data
        sheet I, digital outputs: reset when the process data watchdog expires); with no pins behind the
        emulated ESC the register itself holds 0 (docs/decisions.md)."""
        for sm in self.io_sms:
            self.mem[sm.start:sm.end] = bytes(sm.end - sm.start)

    def _locked(self, address: int, end: int) -> bool:
        """The access [address, end) touches no running SyncManager but the buffer of one the PDI
        deactivated: the ESC refuses it (no working counter), counted."""
        for start, stop in self.locked:
            if start < end and address < stop:
                self.stats.refused_accesses += 1
                return True
        return False

    def _register_write(self, address: int, end: int, data: bytes | bytearray | memoryview) -> None:
        mem = self.mem
        stop = min(end, RAM_START)
        old = bytes(mem[address:stop])
        mem[address:stop] = data[:stop - address]
        ro = self.ro
        if any(ro[address:stop]):
            for a in range(address, stop):
                if ro[a]:
                    mem[a] = old[a - address]
        if end > REG_SII_CONTROL and address < REG_SII_CONTROL + 2:
            self.sii.command()
        if end > REG_AL_CONTROL and address < REG_AL_CONTROL + 2:
            self.events.append(AlControlRequested(U16.unpack_from(mem, REG_AL_CONTROL)[0]))
        if end > REG_FMMU and address < REG_FMMU + 16 * self.n_fmmu:
            self._rebuild_fmmus()
        if end > REG_SM and address < REG_SM + 8 * self.n_sm:
            self.rebuild_sms(old, address)
        if end > 0x0900 and address < 0x09B0:
            self.dc.write(address, end, old)
        if self.wd_changed is not None and ((end > REG_WD_DIVIDER and address < REG_WD_DIVIDER + 2)
                                            or (end > REG_WD_TIME_SM and address < REG_WD_TIME_SM + 2)):
            self.wd_changed()

    # ------------------------------------------------------------------ logical accesses (FMMUs)
    def fmmu_write(self, f: Fmmu, buf: bytearray, off: int, laddr: int, lend: int) -> bool:
        """The write access of FMMU ``f`` for the frame's logical range [laddr, lend) at ``off``."""
        if f.simple:
            o0 = max(laddr, f.lstart)
            o1 = min(lend, f.lend)
            fo = off + o0 - laddr
            return self.ecat_write(f.phys + o0 - f.lstart, buf[fo:fo + o1 - o0])  # a copy: the frame moves on
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

    def fmmu_read(self, f: Fmmu, buf: bytearray, off: int, laddr: int, lend: int) -> bool:
        """The read access of FMMU ``f`` into the frame's logical range [laddr, lend) at ``off``."""
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
    def _fmmu_bits(f: Fmmu, laddr: int, lend: int) -> list[tuple[int, int]]:
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
                out.append(Fmmu(lstart, length, b0 & 7, b1 & 7, phys, pbit & 7, ftype))
        self.fmmus = tuple(out)

    def rebuild_sms(self, old: bytes, address: int, *, master: bool = True) -> None:
        """Recompute the SyncManagers the ESC runs after a write of their registers.

        An enabled SyncManager is activated only when its buffer starts in process RAM and does not
        overlap a lower activated SyncManager: registers and process RAM are separate (ET1100 data
        sheet II: 0x0000-0x0FFF registers, process RAM from 0x1000), so a buffer over the registers
        would let mailbox data overwrite AL status and friends. The one exception is a buffered output
        SyncManager inside the Digital I/O Output Data register 0x0F00:0x0F03
        (:attr:`SmConfig.on_output_register`, an EL2008's outputs): it runs as one in RAM. The master sees
        the refusal through the firmware (the SM-change event :class:`SmChanged`: AL status code
        0x0016 for the mailbox, 0x001D/0x001E for process data, as SOES does on its SM-change
        event); its next normal configuration of the SyncManager activates it again. ``master``: the
        write came from the master (the firmware gets the event); False for the PDI's own deactivation.
        """
        out: list[_Sm] = []
        io: list[_Sm] = []
        locked: list[tuple[int, int]] = []
        mem = self.mem
        refused = 0
        for i in range(self.n_sm):
            base = REG_SM + 8 * i
            cfg = self.sm_config(i)
            on_io = cfg.start < RAM_START and cfg.on_output_register
            if cfg.enabled and mem[base + 7] & SM_PDI_DISABLE and (on_io or cfg.start >= RAM_START):
                locked.append((cfg.start, cfg.start + cfg.length))
            o = base + 6 - address
            old_act = old[o] if 0 <= o < len(old) else mem[base + 6]
            runs = cfg.enabled and not mem[base + 7] & SM_PDI_DISABLE
            if runs and ((cfg.start < RAM_START and not on_io) or any(
                    s.start < cfg.start + cfg.length and cfg.start < s.end for s in (io if on_io else out))):
                runs = False
                refused += 1
            if not cfg.enabled or (not runs and not mem[base + 7] & SM_PDI_DISABLE):
                mem[base + 5] &= ~(SM_STATUS_FULL | SM_STATUS_WRITE_EVENT) & 0xFF
            elif runs and cfg.mailbox and not cfg.ecat_writes and (cfg.activate ^ old_act) & SM_ACT_REPEAT:
                self._mailbox_repeat(i, cfg)
            if runs:
                (io if on_io else out).append(_Sm(cfg))
        self.stats.refused_sms += refused
        self._sms = tuple(out)
        self.io_sms = tuple(io)
        self.active_sms = frozenset(s.index for s in out + io)
        self.locked = tuple(locked)
        if master:
            self.events.append(SM_CHANGED)

    def _mailbox_repeat(self, index: int, cfg: SmConfig) -> None:
        """Repeat request toggled: put the last message back and acknowledge (ETG.1000.4 mailbox)."""
        base = REG_SM + 8 * index
        if self.mbx_last:
            self.store(cfg.start, self.mbx_last[:cfg.length].ljust(cfg.length, b"\0"))
            self.mem[base + 5] |= SM_STATUS_FULL
        self.mem[base + 7] = (self.mem[base + 7] & ~SM_PDI_REPEAT_ACK) | (cfg.activate & SM_ACT_REPEAT)

    def stop_outputs(self) -> bool:
        """The firmware left OP by itself (SM watchdog, a device error): it deactivates the output
        SyncManager from the PDI side (0x0807 + 8n bit 0), as SOES's ESC_stopoutput and Beckhoff's
        slave stack do, so the master's output writes are refused and no longer count in the working
        counter (ET1100 data sheet II 0x0807: "SyncManager deactivated and reset. SyncManager locks
        access to Memory area") until :meth:`start_outputs`. True when it was running."""
        if self.outputs_stopped or not 0 <= self.output_sm < self.n_sm:
            return False
        self.outputs_stopped = True
        self.mem[REG_SM + 8 * self.output_sm + 7] |= SM_PDI_DISABLE
        self.rebuild_sms(bytes(self.mem[REG_SM:REG_SM + 8 * self.n_sm]), REG_SM, master=False)
        return True

    def start_outputs(self) -> None:
        """The master took the slave through a state change: the firmware activates the output
        SyncManager it stopped (SOES's ESC_startoutput on SAFEOP -> OP); nothing when it runs."""
        if not self.outputs_stopped:
            return
        self.outputs_stopped = False
        self.mem[REG_SM + 8 * self.output_sm + 7] &= ~SM_PDI_DISABLE & 0xFF
        self.rebuild_sms(bytes(self.mem[REG_SM:REG_SM + 8 * self.n_sm]), REG_SM, master=False)

    def release_unused_sms(self) -> None:
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
            self.rebuild_sms(bytes(mem[REG_SM:REG_SM + 8 * self.n_sm]), REG_SM, master=False)
