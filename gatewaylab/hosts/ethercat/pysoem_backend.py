"""SOEM through pysoem on a network interface: the I/O adapter of :class:`~.backend.MasterBackend`.

The contract and the rules both backends keep are in ``backend.py`` (docs/ethercat-host.md), what
both share in ``shared.py``; this file holds the part that touches a NIC (pysoem, a lock), as the
architecture's naming rule wants for I/O adapters (``wire*`` files).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any

from gatewaylab.common.clock import Clock, RealTimeClock
from gatewaylab.common.errors import ProtocolError
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError, MailboxError, MasterError, SdoAbort
from gatewaylab.ethercat.esc import (
    REG_AL_CONTROL,
    REG_AL_STATUS,
    REG_SII_CONFIG,
    REG_SII_CONTROL,
    REG_SII_DATA,
    AlState,
)
from gatewaylab.ethercat.sii import SiiInfo, parse_sii
from gatewaylab.hosts.ethercat.backend import EntryInfo, MasterTimeout, ObjectInfo, ProgressFn, SlaveIdentity
from gatewaylab.hosts.ethercat.shared import (
    AL_ERROR,
    INFO_ATTEMPTS,
    POLL,
    REGISTER_ATTEMPTS,
    RETRY_SETTLE,
    SCAN_ATTEMPTS,
    SCAN_RETRY,
    STATES,
    U16,
    U32,
    MailboxPort,
    await_state,
    register_read,
    register_write,
    sii_complete,
    state_of,
)

__all__ = ["PysoemBackend"]


class _PysoemRegisters:
    """:class:`~gatewaylab.hosts.ethercat.shared.Registers` over pysoem's FPRD/FPWR of one slave."""

    def __init__(self, backend: PysoemBackend) -> None:
        self.backend = backend

    def read(self, position: int, address: int, length: int) -> bytes | None:
        slave = self.backend._slave(position)
        clock = self.backend.clock
        deadline = clock.now() + self.backend.timeout
        while True:          # a stalled slave gets the mailbox timeout, not one frame's 50 ms
            try:
                return bytes(slave._fprd(address, length, self.backend.register_timeout_us))
            except self.backend._pysoem.WkcError:
                if clock.now() >= deadline:
                    return None

    def write(self, position: int, address: int, data: bytes) -> bool | None:
        """One attempt; None when it is not known to have failed: pysoem's WkcError does not say
        whether the slave refused the write (working counter 0) or its answer came back too late
        (EC_NOFRAME), after which the write may well have landed."""
        try:
            self.backend._slave(position)._fpwr(address, bytes(data), self.backend.register_timeout_us)
        except self.backend._pysoem.WkcError:
            return None
        return True


class PysoemBackend:
    """:class:`MasterBackend` on a network interface through SOEM (pysoem); needs root or CAP_NET_RAW."""

    def __init__(self, ifname: str, *, timeout: float = 3.0, pd_timeout_us: int = 20_000,
                 register_timeout_us: int = 50_000, preop: bool = True) -> None:
        try:
            import pysoem
        except ImportError:  # pragma: no cover - pysoem is a test/dev dependency
            raise MasterError("PysoemBackend needs pysoem (pip install pysoem)") from None
        self._pysoem: Any = pysoem
        self.ifname = ifname
        self.clock: Clock = RealTimeClock()
        self.timeout = timeout
        self.pd_timeout_us = pd_timeout_us
        self.register_timeout_us = register_timeout_us
        self.wkc_errors = 0
        self.last_wkc = 0
        self._lock = threading.RLock()
        self._sii: dict[int, bytes] = {}
        self._sii_info: dict[int, SiiInfo] = {}
        self._outputs: list[bytearray] = []
        self._inputs: list[bytes] = []
        self._mapped = False
        self._dc = False
        self._closed = False
        self._slaves: list[Any] = []
        #: the mailbox counter of this backend's own requests per slave (FoE); see _mbx_counter
        self._mbx_counts: dict[int, int] = {}
        self._mbx = MailboxPort(self.clock, _PysoemRegisters(self), timeout, self._mbx_counter)
        master = pysoem.Master()
        master.sdo_read_timeout = round(timeout * 1e6)
        master.sdo_write_timeout = round(timeout * 1e6)
        try:
            master.open(ifname)
        except Exception as exc:  # pysoem raises ConnectionError with SOEM's text
            hint = " (needs root or CAP_NET_RAW)" if os.geteuid() != 0 else ""
            raise MasterError(f"cannot open {ifname}: {exc}{hint}") from None
        self._master = master
        try:
            master.manual_state_change = 1      # config_init/config_map only configure; we request states
            for attempt in range(SCAN_ATTEMPTS):
                # A link just brought up may lose the first frames, and a late EEPROM answer leaves
                # SOEM with a wrong mailbox configuration (the slave refuses PREOP with 0x0016):
                # config_init again, as a master re-initialises a line.
                last = attempt == SCAN_ATTEMPTS - 1
                self._sii.clear()
                self._sii_info.clear()
                if master.config_init() <= 0:
                    if last:
                        raise MasterTimeout(f"no EtherCAT slaves answer on {ifname}")
                    self.clock.wait(SCAN_RETRY)
                    continue
                self._slaves = list(master.slaves)
                if not preop:
                    break
                try:
                    self.request_state(AlState.PREOP)
                    break
                except AlStatusError as exc:
                    if last or exc.code not in (AlStatusCode.INVALID_MAILBOX_CONFIG,
                                                AlStatusCode.INVALID_MAILBOX_CONFIG_BOOT):
                        raise
                    self.clock.wait(SCAN_RETRY)
        except BaseException:
            self.close()
            raise

    # -- helpers -----------------------------------------------------------------------------
    def _slave(self, position: int) -> Any:
        if not 0 <= position < len(self._slaves):
            raise MasterError(f"no slave at position {position} ({len(self._slaves)} slaves)")
        return self._slaves[position]

    def _positions(self, position: int | None) -> list[int]:
        if position is None:
            return list(range(len(self._slaves)))
        self._slave(position)
        return [position]

    def _mbx_counter(self, position: int) -> int:
        """ETG.1000.4 mailbox counter of the next own request: 0 ('not used', never taken for a repeat)
        first and after SOEM's own mailbox calls (whose counters SOEM keeps), then 1..7 in turn, so a
        request written again after a lost answer (:meth:`MailboxPort.send`) is dropped by the slave as
        a repeat instead of being served twice (an FoE DATA packet twice: PACKET_NUMBER_WRONG)."""
        last = self._mbx_counts.get(position)
        self._mbx_counts[position] = nxt = 0 if last is None else last % 7 + 1
        return nxt

    def _mailbox_call(self, what: str, fn: Callable[..., Any], *args: Any) -> Any:
        """A pysoem mailbox call with its errors turned into the contract's. A call SOEM saw no
        answer to (or got an unexpected reply for) is made once more, after the mailboxes were read
        out: SOEM gives the slave a fixed 20 ms to take a mailbox write, which a stall of a loaded
        machine can exceed."""
        self._mbx_counts.clear()   # SOEM's counter was last: own requests start again at 0
        p = self._pysoem
        try:
            try:
                return fn(*args)
            except (p.WkcError, p.PacketError):
                self.clock.wait(RETRY_SETTLE)     # a late reply of the first attempt arrives meanwhile
                for s in self._slaves:
                    try:
                        s.mbx_receive()           # and is read out before the second attempt
                    except Exception:  # draining only: emergencies and errors are dropped
                        pass
                return fn(*args)
        except p.SdoError as exc:
            raise SdoAbort(int(exc.abort_code), what) from None
        except p.WkcError:
            raise MasterTimeout(f"{what}: no answer within {self.timeout:g} s") from None
        except p.MailboxError as exc:
            raise MailboxError(f"{what}: mailbox error 0x{exc.error_code:04X} ({exc.desc})",
                               int(exc.error_code)) from None
        except p.PacketError as exc:
            raise ProtocolError(f"{what}: SOEM packet error {exc.error_code}", int(exc.error_code)) from None

    # -- MasterBackend -----------------------------------------------------------------------
    def slaves(self) -> list[SlaveIdentity]:
        """The slaves config_init found, in line order (station = 0x1001 + position, as SOEM assigns),
        with the identity of their SII."""
        out = []
        for pos in range(len(self._slaves)):
            info = self.sii_info(pos)     # our own checked SII read, not SOEM's copy
            out.append(SlaveIdentity(pos, 0x1001 + pos, info.name, info.vendor_id, info.product_code,
                                     info.revision, info.serial))
        return out

    def al_status(self, position: int) -> tuple[int, int]:
        """(AL status register with the error flag, AL status code), read now."""
        regs = _PysoemRegisters(self)
        for _attempt in range(REGISTER_ATTEMPTS):
            raw = regs.read(position, REG_AL_STATUS, 6)
            if raw is None:
                raise MasterTimeout(f"slave {position} does not answer")
            status = U16.unpack_from(raw, 0)[0]
            # SOEM matches a reply by its index byte only: a very late frame of an earlier request
            # can stand in for the answer (shared notes soem-interop pitfall 2); read again.
            if not status & 0xFFE0 and status & 0x0F in STATES:
                return status, U16.unpack_from(raw, 4)[0]
        raise ProtocolError(f"slave {position}: implausible AL status 0x{status:04X}")

    def state(self, position: int) -> tuple[AlState, int]:
        """(AL state, AL status code) of one slave."""
        status, code = self.al_status(position)
        return state_of(status), code

    def _set_boot_mailbox(self, position: int, boot: bool) -> None:
        """BOOT uses the bootstrap mailbox of SII words 0x14..0x17 (pysoem amend_mbx, slave in INIT)."""
        b = self.sii_info(position).bootstrap_mailbox
        if not b[1]:
            return
        info = self.sii_info(position)
        (wo, wl), (ro, rl) = ((b[0], b[1]), (b[2], b[3])) if boot else (info.mailbox_out, info.mailbox_in)
        s = self._slave(position)
        s.amend_mbx("out", wo, wl)
        s.amend_mbx("in", ro, rl)

    def request_state(self, state: AlState, position: int | None = None, timeout: float = 5.0) -> AlState:
        """Request ``state`` (all slaves, or one) and wait until reached, exchanging process data
        meanwhile once mapped; an error flag acknowledges first. AlStatusError carries the code."""
        for pos in self._positions(position):
            status, _code = self.al_status(pos)
            current = status & 0x0F
            if state == AlState.BOOT and current != AlState.BOOT:
                self._set_boot_mailbox(pos, True)
            elif current == AlState.BOOT and state != AlState.BOOT:
                self._set_boot_mailbox(pos, False)
            self._write_control(pos, int(state) | (AL_ERROR if status & AL_ERROR else 0))
            await_state(self, pos, state, timeout, exchanging=self._mapped)
        return state

    def _write_control(self, pos: int, control: int) -> None:
        regs = _PysoemRegisters(self)
        for _attempt in range(REGISTER_ATTEMPTS):
            if regs.write(pos, REG_AL_CONTROL, U16.pack(control)):
                return
        raise MasterTimeout(f"slave {pos} does not answer")

    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes:
        """CoE SDO upload through SOEM (objects up to 64 KiB)."""
        s = self._slave(position)
        return bytes(self._mailbox_call(f"SDO upload 0x{index:04X}:{subindex:02X}", s.sdo_read, index, subindex,
                                        65536, complete))

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes, complete: bool = False) -> None:
        """CoE SDO download through SOEM."""
        s = self._slave(position)
        self._mailbox_call(f"SDO download 0x{index:04X}:{subindex:02X}", s.sdo_write, index, subindex,
                           bytes(data), complete)

    def _objects(self, position: int) -> list[Any]:
        p = self._pysoem
        for attempt in range(INFO_ATTEMPTS):
            try:
                return list(self._mailbox_call("SDO information", lambda: self._slave(position).od))
            except p.SdoInfoError as exc:
                if attempt == INFO_ATTEMPTS - 1:
                    raise ProtocolError(f"SDO information: {exc.message}") from None
        return []

    @staticmethod
    def _text(value: Any) -> str:
        return value.decode("latin-1") if isinstance(value, bytes) else str(value)

    def _info(self, obj: Any) -> ObjectInfo:
        for _attempt in range(INFO_ATTEMPTS - 1):
            try:
                return self._info_once(obj)
            except ProtocolError:
                pass
        return self._info_once(obj)     # the last attempt: its ProtocolError goes to the caller

    def _info_once(self, obj: Any) -> ObjectInfo:
        p = self._pysoem
        try:
            raw_entries = list(obj.entries)
            if raw_entries:
                entries = tuple(EntryInfo(i, int(e.data_type), int(e.bit_length), int(e.obj_access),
                                          self._text(e.name)) for i, e in enumerate(raw_entries))
                max_sub = len(raw_entries) - 1
            else:  # a VAR: SOEM describes its one entry through the object
                entries = (EntryInfo(0, int(obj.data_type), int(obj.bit_length), int(obj.obj_access),
                                     self._text(obj.name)),)
                max_sub = 0
            return ObjectInfo(int(obj.index), int(obj.object_code), int(obj.data_type), max_sub,
                              self._text(obj.name), entries)
        except p.SdoInfoError as exc:
            raise ProtocolError(f"SDO information of 0x{int(obj.index):04X}: {exc.message}") from None

    def object_info(self, position: int, index: int) -> ObjectInfo:
        """One object and its entries by SDO Information (SOEM reads the OD list, then this object)."""
        for obj in self._objects(position):
            if int(obj.index) == index:
                return self._info(obj)
        raise SdoAbort(0x06020000, f"0x{index:04X} is not in the OD list")

    def object_dictionary(self, position: int) -> list[ObjectInfo]:
        """Every object of the slave's dictionary by SDO Information."""
        return [self._info(obj) for obj in self._objects(position)]

    def foe_read(self, position: int, name: str, password: int = 0, *, progress: ProgressFn | None = None) -> bytes:
        """Read a file by FoE through the mailbox registers; FoeError carries the slave's code."""
        self._slave(position)
        return self._mbx.foe_read(position, name, password, progress)

    def foe_write(self, position: int, name: str, data: bytes, password: int = 0, *,
                  progress: ProgressFn | None = None) -> None:
        """Write a file by FoE through the mailbox registers; FoeError carries the slave's code."""
        self._slave(position)
        self._mbx.foe_write(position, name, data, password, progress)

    def reg_read(self, position: int, address: int, length: int) -> bytes:
        """ESC registers by FPRD, IgH's ``reg_read``; MasterTimeout when the slave does not answer."""
        self._slave(position)
        return register_read(_PysoemRegisters(self), position, address, length)

    def reg_write(self, position: int, address: int, data: bytes) -> None:
        """ESC registers by FPWR, IgH's ``reg_write``."""
        self._slave(position)
        register_write(_PysoemRegisters(self), position, address, data)

    def sii_read(self, position: int) -> bytes:
        """The SII EEPROM image up to its END category, read through the ESC's EEPROM interface
        (0x0500-0x050F) with status checks: SOEM's ``eeprom_read`` returns 0 for a failed read."""
        cached = self._sii.get(position)
        if cached is not None:
            return cached
        regs = _PysoemRegisters(self)
        if not regs.write(position, REG_SII_CONFIG, b"\x02\x00") or \
                not regs.write(position, REG_SII_CONFIG, b"\x00\x00"):   # EEPROM to the master (SOEM does so)
            raise MasterTimeout(f"slave {position} does not answer")
        img = bytearray()
        while len(img) < 65536:
            img += self._sii_chunk(regs, position, len(img) // 2)
            if len(img) >= 0x84 and sii_complete(img):
                break
        self._sii[position] = out = bytes(img)
        return out

    def _sii_chunk(self, regs: _PysoemRegisters, position: int, word: int) -> bytes:
        """4 or 8 bytes from EEPROM word ``word`` (0x0502 bit 6 tells the read size)."""
        deadline = self.clock.now() + self.timeout
        while self.clock.now() < deadline:
            if regs.write(position, REG_SII_CONTROL, U16.pack(0x0100) + U32.pack(word)):
                status = regs.read(position, REG_SII_CONTROL, 2)
                while status is not None and U16.unpack(status)[0] & 0x8000 and self.clock.now() < deadline:
                    self.clock.wait(POLL)               # busy
                    status = regs.read(position, REG_SII_CONTROL, 2)
                if status is not None and not U16.unpack(status)[0] & 0xF800:
                    size = 8 if U16.unpack(status)[0] & 0x0040 else 4
                    data = regs.read(position, REG_SII_DATA, size)
                    if data is not None:
                        return data
            self.clock.wait(POLL)
        raise MasterTimeout(f"slave {position}: SII word 0x{word:04X} not readable within {self.timeout:g} s")

    def sii_info(self, position: int) -> SiiInfo:
        """The parsed SII (identity, mailboxes, SyncManagers)."""
        info = self._sii_info.get(position)
        if info is None:
            self._sii_info[position] = info = parse_sii(self.sii_read(position))
        return info

    def config_map(self) -> int:
        """SOEM's config_map (PDO assignment by SDO -> SMs, FMMUs); returns the IO map size (no state change)."""
        p = self._pysoem
        try:
            size = int(self._master.config_map())
        except p.ConfigMapError as exc:
            first = exc.error_list[0] if exc.error_list else None
            if isinstance(first, p.SdoError):
                raise SdoAbort(int(first.abort_code), "config_map") from None
            raise ProtocolError(f"config_map failed: {exc.error_list}") from None
        self._outputs = [bytearray(len(s.output)) for s in self._slaves]
        self._inputs = [bytes(s.input) for s in self._slaves]
        self._mapped = True
        return size

    def configure_dc(self, position: int, cycle_ns: int, shift_ns: int = 0) -> None:
        """SOEM config_dc (once), then SYNC0 every ``cycle_ns`` with ``shift_ns`` (0 switches it off)."""
        s = self._slave(position)
        if not self._dc:
            self._master.config_dc()
            self._dc = True
        if cycle_ns <= 0:
            s.dc_sync(False, 0)
        else:
            s.dc_sync(True, cycle_ns, shift_ns)

    def outputs(self, position: int) -> memoryview:
        """The slave's RxPDO bytes: write them, the next :meth:`exchange` sends them."""
        self._slave(position)
        if not self._mapped:
            raise MasterError("config_map first")
        return memoryview(self._outputs[position])

    def inputs(self, position: int) -> bytes:
        """The slave's TxPDO bytes as the last :meth:`exchange` brought them."""
        self._slave(position)
        if not self._mapped:
            raise MasterError("config_map first")
        return self._inputs[position]

    def exchange(self) -> tuple[int, int]:
        """One process-data cycle (send, receive within ``pd_timeout_us``); (wkc, expected), mismatches counted."""
        if not self._mapped:
            raise MasterError("config_map first")
        with self._lock:
            for s, out in zip(self._slaves, self._outputs, strict=True):
                if out:
                    s.output = bytes(out)
            self._master.send_processdata()
            wkc = int(self._master.receive_processdata(self.pd_timeout_us))
            self._inputs = [bytes(s.input) for s in self._slaves]
            expected = int(self._master.expected_wkc)
        self.last_wkc = wkc
        if wkc != expected:
            self.wkc_errors += 1
        return wkc, expected

    def close(self) -> None:
        """Close the interface (SOEM leaves it in promiscuous mode)."""
        if not self._closed:
            self._closed = True
            self._master.close()
