"""One small EtherCAT master abstraction for the host libraries: the same calls in process and on a NIC.

The ECAN-Lite and esd host libraries, the python-can interfaces over them and ``gatewaylab ec``
talk to slaves through :class:`MasterBackend`. Two implementations exist:

* :class:`InProcessBackend` -- the in-process :class:`~gatewaylab.hosts.ethercat.master.Master` on a rig's
  segment (no root, simulated or real clock; ``InProcessBackend.from_rig(rig)``);
* :class:`~gatewaylab.hosts.ethercat.pysoem_backend.PysoemBackend` -- SOEM through pysoem on a network
  interface (root); an I/O adapter, so it lives in ``wire_backend.py`` and is re-exported here.

Rules both keep (docs/ethercat-host.md):

* a new backend has scanned the line and every slave is in PREOP (IgH's default state);
* ``config_map`` only maps (SyncManagers, FMMUs from the PDO assignment); the caller requests
  SAFEOP and OP with :meth:`~MasterBackend.request_state`, which keeps process data flowing
  while it waits, as a master must for SAFEOP -> OP;
* errors carry wire codes: :class:`~gatewaylab.od.SdoAbort` (abort code),
  :class:`~gatewaylab.ethercat.errors.AlStatusError` (AL status code),
  :class:`~gatewaylab.ethercat.errors.FoeError` (FoE error code), :class:`MasterTimeout`
  (no answer; both a gatewaylab error and the builtin :class:`TimeoutError`);
* host code waits with ``backend.clock.wait()``: on a simulated clock time passes only there.

FoE goes through the slave's mailbox SyncManagers with plain register reads and writes on both
backends (:class:`_MailboxPort`), so both report the slave's FoE error code and progress; SOEM's
own FoE functions drop the error code (shared notes ``soem-interop``).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ProtocolError, TimeoutError_
from gatewaylab.ethercat.errors import (
    AlStatusCode,
    AlStatusError,
    FoeError,
    FoeErrorCode,
    MailboxError,
    MasterError,
    SdoAbort,
    WorkingCounterError,
)
from gatewaylab.ethercat.esc import (
    REG_DC_ACTIVATION,
    REG_DC_START_TIME,
    REG_DC_SYNC0_CYCLE,
    REG_DC_SYSTEM_TIME,
    REG_SM,
    AlState,
)
from gatewaylab.ethercat.foe import FOE_HEADER, FoeOpcode, foe_packet
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, decode_mailbox, encode_mailbox
from gatewaylab.ethercat.sii import CATEGORY_HEADER, Category, SiiInfo
from gatewaylab.hosts.ethercat.master import Master

if TYPE_CHECKING:
    from gatewaylab.ethercat.segment import Segment

__all__ = ["EntryInfo", "InProcessBackend", "MasterBackend", "MasterTimeout", "ObjectInfo", "ProgressFn",
           "RigLike", "SlaveIdentity", "al_status_name", "sii_complete"]

U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
U64 = struct.Struct("<Q")
SM_REG = struct.Struct("<HHBBBB")
#: Seconds between two polls of a mailbox or an AL status that is not there yet.
POLL = 0.0005
#: Seconds between two polls of the AL status while a state change is pending.
STATE_POLL = 0.001
#: Seconds from now to the first SYNC0 pulse (SOEM waits 100 ms; in process a short delay is enough).
DC_START_DELAY = 0.01
#: Seconds an FoE slave may keep answering BUSY before the transfer is given up.
FOE_BUSY_TIMEOUT = 10.0
#: Seconds before a DATA packet answered with BUSY is sent again.
FOE_BUSY_RETRY = 0.01
#: config_init attempts before a line counts as empty, and the seconds between them.
SCAN_ATTEMPTS = 3
SCAN_RETRY = 0.2
#: SOEM waits 700 ms for each SDO Information reply; on a loaded machine a request is tried again.
INFO_ATTEMPTS = 3
#: Reads of the AL status over pysoem tried this often while the answer is implausible.
REGISTER_ATTEMPTS = 3
#: Seconds to let a late mailbox reply arrive before a pysoem mailbox call is repeated.
RETRY_SETTLE = 0.05
#: A slave's FoE error text may already end in the code FoeError appends.
FOE_CODE_SUFFIX = re.compile(r"\s*\(FoE error 0x[0-9A-Fa-f]+\)$")
#: The error flag of AL status (bit 4).
AL_ERROR = 0x10

#: ``progress(done_bytes, total_bytes)``; total is 0 while unknown (an FoE read).
ProgressFn = Callable[[int, int], None]


class MasterTimeout(TimeoutError_, TimeoutError):
    """No answer in time: a gatewaylab error with the builtin's type, so ``except TimeoutError`` works."""


@dataclass(frozen=True, slots=True)
class SlaveIdentity:
    """One slave as ``gatewaylab ec slaves`` prints it: its place in the line and its SII identity."""

    position: int
    station: int
    name: str
    vendor_id: int
    product_code: int
    revision: int
    serial: int


@dataclass(frozen=True, slots=True)
class EntryInfo:
    """One subindex as SDO Information describes it (ETG.1000.6 entry description)."""

    subindex: int
    data_type: int
    bit_length: int
    access: int
    name: str


@dataclass(frozen=True, slots=True)
class ObjectInfo:
    """One object as SDO Information describes it (ETG.1000.6 object description) with its entries."""

    index: int
    object_code: int
    data_type: int
    max_subindex: int
    name: str
    entries: tuple[EntryInfo, ...]


@runtime_checkable
class MasterBackend(Protocol):
    """What the host libraries need of an EtherCAT master; the same calls in process and on a real NIC."""

    clock: Clock
    #: Cycles whose working counter differed from the expected one (every :meth:`exchange`).
    wkc_errors: int

    def slaves(self) -> list[SlaveIdentity]: ...
    def state(self, position: int) -> tuple[AlState, int]: ...
    def al_status(self, position: int) -> tuple[int, int]: ...
    def request_state(self, state: AlState, position: int | None = None, timeout: float = 5.0) -> AlState: ...
    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes: ...
    def sdo_download(self, position: int, index: int, subindex: int, data: bytes, complete: bool = False) -> None: ...
    def object_dictionary(self, position: int) -> list[ObjectInfo]: ...
    def object_info(self, position: int, index: int) -> ObjectInfo: ...
    def foe_read(self, position: int, name: str, password: int = 0, *, progress: ProgressFn | None = None) -> bytes: ...
    def foe_write(self, position: int, name: str, data: bytes, password: int = 0, *,
                  progress: ProgressFn | None = None) -> None: ...
    def sii_read(self, position: int) -> bytes: ...
    def reg_read(self, position: int, address: int, length: int) -> bytes: ...
    def reg_write(self, position: int, address: int, data: bytes) -> None: ...
    def sii_info(self, position: int) -> SiiInfo: ...
    def config_map(self) -> int: ...
    def configure_dc(self, position: int, cycle_ns: int, shift_ns: int = 0) -> None: ...
    def outputs(self, position: int) -> memoryview: ...
    def inputs(self, position: int) -> bytes: ...
    def exchange(self) -> tuple[int, int]: ...
    def close(self) -> None: ...


def al_status_name(code: int) -> str:
    """``0x001B SM_WATCHDOG``-style text for an AL status code, for messages and ``ec states``."""
    try:
        return f"0x{code:04X} {AlStatusCode(code).name}"
    except ValueError:
        return f"0x{code:04X}"


def sii_complete(img: bytes | bytearray) -> bool:
    """True once ``img`` holds the SII's END category: a master reads no further."""
    pos = 0x80
    while pos + CATEGORY_HEADER.size <= len(img):
        kind, words = CATEGORY_HEADER.unpack_from(img, pos)
        if kind == Category.END:
            return True
        pos += CATEGORY_HEADER.size + 2 * words
    return False


_STATES = frozenset(int(s) for s in AlState)


class _StatePolled(Protocol):
    clock: Clock

    def al_status(self, position: int) -> tuple[int, int]: ...
    def exchange(self) -> tuple[int, int]: ...


def await_state(backend: _StatePolled, pos: int, state: AlState, timeout: float, *, exchanging: bool) -> None:
    """Poll slave ``pos``'s AL status every STATE_POLL until it shows ``state``, exchanging process
    data meanwhile when the segment is mapped and the target is SAFEOP/OP (the SM watchdog); the
    one wait of every backend. AlStatusError with the slave's code when refused, MasterTimeout."""
    deadline = backend.clock.now() + timeout
    while True:
        status, code = backend.al_status(pos)
        if status & AL_ERROR:
            raise AlStatusError(f"slave {pos} refused {state.name}: AL status 0x{status:02X}, "
                                f"code {al_status_name(code)}", code)
        if status & 0x0F == state:
            return
        if backend.clock.now() >= deadline:
            raise MasterTimeout(f"slave {pos} did not reach {state.name} within {timeout:g} s "
                                f"(AL status 0x{status:02X})")
        if exchanging and state in (AlState.SAFEOP, AlState.OP):
            backend.exchange()
        backend.clock.wait(STATE_POLL)


def _state_of(status: int) -> AlState:
    try:
        return AlState(status & 0x0F)
    except ValueError:
        raise MasterTimeout(f"AL status 0x{status:02X} holds no state (slave lost?)") from None


# ---------------------------------------------------------------------------------------- FoE
class _Registers(Protocol):
    """Register access of one backend: None / False when the slave did not answer (working counter 0)."""

    def read(self, position: int, address: int, length: int) -> bytes | None: ...
    def write(self, position: int, address: int, data: bytes) -> bool | None: ...   # None: answer lost


class _MailboxPort:
    """FoE through a slave's mailbox SyncManagers with plain register access (ETG.1000.6 FoE).

    The mailbox areas are read from the SM0/SM1 registers, so the bootstrap mailbox is used in
    BOOT without further ado. ``counter`` gives the mailbox counter of each request (0 = 'not
    used', which never collides with the counters another stack keeps for the same slave)."""

    def __init__(self, clock: Clock, regs: _Registers, timeout: float, counter: Callable[[int], int]) -> None:
        self.clock = clock
        self.regs = regs
        self.timeout = timeout
        self.counter = counter

    def _wait_for(self, what: str, check: Callable[[], bool], timeout: float | None = None) -> None:
        deadline = self.clock.now() + (self.timeout if timeout is None else timeout)
        while not check():
            if self.clock.now() >= deadline:
                raise MasterTimeout(f"{what}: no answer within {self.timeout:g} s")
            self.clock.wait(POLL)

    def _areas(self, position: int) -> tuple[tuple[int, int], tuple[int, int]]:
        got: list[bytes] = []

        def read() -> bool:
            raw = self.regs.read(position, REG_SM, 16)
            if raw is not None:
                got.append(raw)
            return raw is not None

        self._wait_for(f"slave {position} SyncManagers", read)
        raw = got[0]
        o_start, o_len, *_ = SM_REG.unpack_from(raw, 0)
        i_start, i_len, *_ = SM_REG.unpack_from(raw, 8)
        if not o_len or not i_len:
            raise MasterError(f"slave {position} has no mailbox configured (INIT, or no mailbox)")
        return (o_start, o_len), (i_start, i_len)

    def send(self, position: int, mtype: int, data: bytes) -> None:
        """Write one request into SM0, waiting while the slave has not taken the previous one."""
        (o_start, o_len), _ = self._areas(position)
        raw = encode_mailbox(MailboxMessage(mtype, data, self.counter(position)))
        if len(raw) > o_len:
            raise MasterError(f"mailbox message of {len(raw)} bytes exceeds the {o_len}-byte mailbox")
        padded = raw.ljust(o_len, b"\0")

        def attempt() -> bool:
            took = self.regs.write(position, o_start, padded)
            if took is None:     # refused, or the answer was lost: did the request land? (a repeat
                return self._landed(position)   # would be a second request, e.g. an FoE packet twice)
            return took

        self._wait_for("mailbox write", attempt)

    def _landed(self, position: int) -> bool:
        """After a write not known to have landed: the request is in (SM0 'mailbox full') or already
        answered (SM1 full) within RETRY_SETTLE (a slave that took it may need a moment to post
        its reply); requests here go one at a time, so SM0 was empty before."""
        deadline = self.clock.now() + RETRY_SETTLE
        while True:
            raw = self.regs.read(position, REG_SM, 16)
            if raw is not None and (raw[5] & 0x08 or raw[13] & 0x08):
                return True
            if self.clock.now() >= deadline:
                return False
            self.clock.wait(POLL)

    def receive(self, position: int, mtype: int) -> MailboxMessage:
        """The next reply of type ``mtype`` from SM1 (other messages, e.g. emergencies, are dropped)."""
        _, (i_start, i_len) = self._areas(position)
        out: list[MailboxMessage] = []

        def poll() -> bool:
            status = self.regs.read(position, REG_SM + 8 + 5, 1)
            if status is None or not status[0] & 0x08:
                return False
            raw = self.regs.read(position, i_start, i_len)
            if raw is None:
                return False
            msg = decode_mailbox(raw)
            if msg.type in (mtype, MailboxType.ERROR):
                out.append(msg)
                return True
            return False

        self._wait_for("mailbox read", poll)
        msg = out[0]
        if msg.type == MailboxType.ERROR:
            code = U16.unpack_from(msg.data, 2)[0] if len(msg.data) >= 4 else 0
            raise MailboxError(f"mailbox error reply 0x{code:04X}", code)
        return msg

    def _foe(self, position: int, packet: bytes) -> tuple[int, int, bytes]:
        self.send(position, MailboxType.FOE, packet)
        data = self.receive(position, MailboxType.FOE).data
        if len(data) < FOE_HEADER.size:
            raise ProtocolError("FoE reply shorter than its header")
        opcode, _r, word = FOE_HEADER.unpack_from(data, 0)
        rest = data[FOE_HEADER.size:]
        if opcode == FoeOpcode.ERR:
            text = rest.decode("latin-1", "replace").rstrip("\0")
            text = FOE_CODE_SUFFIX.sub("", text) or _foe_text(word)
            raise FoeError(text, word)
        return opcode, word, rest

    def foe_write(self, position: int, name: str, data: bytes, password: int,
                  progress: ProgressFn | None) -> None:
        """WRQ, then DATA packets acknowledged one by one; a short (or empty) last packet ends it."""
        (_o_start, o_len), _ = self._areas(position)
        max_data = o_len - 6 - FOE_HEADER.size
        opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.WRQ, password, name.encode("latin-1")))
        if opcode != FoeOpcode.ACK or word != 0:
            raise FoeError("write request not acknowledged", FoeErrorCode.ILLEGAL)
        packet = done = 0
        while True:
            chunk = data[done:done + max_data]
            packet += 1
            opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.DATA, packet, chunk))
            deadline = self.clock.now() + FOE_BUSY_TIMEOUT
            while opcode == FoeOpcode.BUSY:
                if self.clock.now() >= deadline:
                    raise MasterTimeout("FoE slave stayed busy")
                self.clock.wait(FOE_BUSY_RETRY)
                opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.DATA, packet, chunk))
            if opcode != FoeOpcode.ACK or word != packet:
                raise FoeError(f"data packet {packet} not acknowledged", FoeErrorCode.PACKET_NUMBER_WRONG)
            done += len(chunk)
            if progress is not None:
                progress(done, len(data))
            if len(chunk) < max_data:
                return

    def foe_read(self, position: int, name: str, password: int, progress: ProgressFn | None) -> bytes:
        """RRQ, then DATA packets, each acknowledged; a short last packet ends the file."""
        _, (_i_start, i_len) = self._areas(position)
        max_data = i_len - 6 - FOE_HEADER.size
        out = bytearray()
        opcode, word, rest = self._foe(position, foe_packet(FoeOpcode.RRQ, password, name.encode("latin-1")))
        while True:
            if opcode != FoeOpcode.DATA:
                raise FoeError(f"unexpected FoE opcode {opcode}", FoeErrorCode.ILLEGAL)
            out += rest
            if progress is not None:
                progress(len(out), 0)
            if len(rest) < max_data:
                self.send(position, MailboxType.FOE, foe_packet(FoeOpcode.ACK, word))
                return bytes(out)
            opcode, word, rest = self._foe(position, foe_packet(FoeOpcode.ACK, word))


def _foe_text(code: int) -> str:
    try:
        return FoeErrorCode(code).name.replace("_", " ").lower()
    except ValueError:
        return "FoE error"


# ---------------------------------------------------------------------------------------- in process
class RigLike(Protocol):
    """What :meth:`InProcessBackend.from_rig` needs of a rig (``gatewaylab.rig.runtime.Rig``)."""

    @property
    def clock(self) -> Clock: ...

    @property
    def participants(self) -> Sequence[Any]: ...


class _MasterRegisters:
    """:class:`_Registers` over the in-process master (configured addresses of its scan)."""

    def __init__(self, master: Master) -> None:
        self.master = master

    def read(self, position: int, address: int, length: int) -> bytes | None:
        try:
            return self.master.fprd(self.master.slave(position).station, address, length)
        except (TimeoutError_, WorkingCounterError):
            return None

    def write(self, position: int, address: int, data: bytes) -> bool:
        try:
            self.master.fpwr(self.master.slave(position).station, address, data)
        except (TimeoutError_, WorkingCounterError):
            return False
        return True


def register_read(regs: _Registers, position: int, address: int, length: int) -> bytes:
    """``length`` bytes of a slave's registers, or MasterTimeout naming them (both backends)."""
    if not 0 <= address <= 0xFFFF or not 1 <= length <= 0x10000 - address:
        raise MasterError(f"registers 0x{address:04X}+{length} are outside the ESC's 64 KiB")
    data = regs.read(position, address, length)
    if data is None:
        raise MasterTimeout(f"slave {position}: no answer reading {length} byte(s) at 0x{address:04X}")
    return bytes(data)


def register_write(regs: _Registers, position: int, address: int, data: bytes) -> None:
    """Write a slave's registers, or MasterTimeout (the write was not acknowledged)."""
    if not 0 <= address <= 0xFFFF or not 1 <= len(data) <= 0x10000 - address:
        raise MasterError(f"registers 0x{address:04X}+{len(data)} are outside the ESC's 64 KiB")
    if not regs.write(position, address, data):
        raise MasterTimeout(f"slave {position}: writing {len(data)} byte(s) at 0x{address:04X} was not "
                            "acknowledged (working counter 0 or no answer)")


def _locked_link(segment: Segment, lock: Any) -> Callable[[bytes], bytes | None]:
    """A master link through ``segment`` under the clock's lock (a rig's loop may run the devices)."""

    def link(raw: bytes) -> bytes | None:
        buf = bytearray(raw)
        with lock:
            ok = segment.process(buf)
        return bytes(buf) if ok else None

    return link


class InProcessBackend:
    """:class:`MasterBackend` over the in-process :class:`Master`: frames through the ESC code, no network."""

    def __init__(self, master: Master, *, preop: bool = True) -> None:
        self.master = master
        self.clock: Clock = master.clock
        self.wkc_errors = 0
        self.last_wkc = 0
        self._sii: dict[int, SiiInfo] = {}
        self._mapped = False
        self._mbx = _MailboxPort(self.clock, _MasterRegisters(master), master.timeout, self._next_counter)
        if not master.slaves:
            self._call(master.scan)
        if preop:
            for s in master.slaves:
                if self.state(s.position)[0] == AlState.INIT:
                    self.request_state(AlState.PREOP, s.position)

    @classmethod
    def from_rig(cls, rig: RigLike, *, timeout: float = 0.1, preop: bool = True) -> InProcessBackend:
        """A master on the rig's EtherCAT segment (its ``[ethercat]`` section, or its EtherCAT devices
        in file order when it has none), frames under the rig clock's lock. Start the rig first so
        its devices run."""
        from gatewaylab.ethercat.segment import Segment as _Segment
        from gatewaylab.plugin.capabilities import ethercat_devices, segment_of

        segment = segment_of(rig.participants)
        if segment is None:
            devices = ethercat_devices(rig.participants)
            if not devices:
                raise MasterError("the rig has no EtherCAT devices")
            segment = _Segment([d.slave for d in devices])
        master = Master(rig.clock, link=_locked_link(segment, rig.clock.lock), timeout=timeout)
        return cls(master, preop=preop)

    # -- helpers -----------------------------------------------------------------------------
    def _next_counter(self, position: int) -> int:
        s = self.master.slave(position)
        s.mbx_counter = s.mbx_counter % 7 + 1
        return s.mbx_counter

    def _call(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Run a master call, turning its timeout into :class:`MasterTimeout`."""
        try:
            return fn(*args, **kwargs)
        except MasterTimeout:
            raise
        except TimeoutError_ as exc:
            raise MasterTimeout(str(exc)) from None

    def _positions(self, position: int | None) -> list[int]:
        if position is None:
            return [s.position for s in self.master.slaves]
        self.master.slave(position)
        return [position]

    # -- MasterBackend -----------------------------------------------------------------------
    def slaves(self) -> list[SlaveIdentity]:
        """The slaves of the scan, in line order."""
        return [SlaveIdentity(s.position, s.station, s.name, s.vendor_id, s.product_code, s.revision, s.serial)
                for s in self.master.slaves]

    def al_status(self, position: int) -> tuple[int, int]:
        """(AL status register with the error flag, AL status code)."""
        status, code = self._call(self.master.al_status, position)
        return int(status), int(code)

    def state(self, position: int) -> tuple[AlState, int]:
        """(AL state, AL status code) of one slave."""
        status, code = self.al_status(position)
        return _state_of(status), code

    def request_state(self, state: AlState, position: int | None = None, timeout: float = 5.0) -> AlState:
        """Request ``state`` (all slaves, or one) and wait until reached; an error flag acknowledges
        first. Raises AlStatusError with the slave's code when refused, MasterTimeout when not reached."""
        m = self.master
        for pos in self._positions(position):
            status, _code = self.al_status(pos)
            try:
                self._call(m.request_state, pos, state, ack=bool(status & AL_ERROR))
            except AlStatusError:
                pass  # checked below: the slave may still be on its way
            await_state(self, pos, state, timeout, exchanging=self._mapped)
            m.slave(pos).boot = state == AlState.BOOT
        return state

    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes:
        """CoE SDO upload (expedited, normal or segmented; complete access with ``complete``)."""
        return bytes(self._call(self.master.sdo_upload, position, index, subindex, complete))

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes, complete: bool = False) -> None:
        """CoE SDO download (expedited, normal or segmented; complete access with ``complete``)."""
        self._call(self.master.sdo_download, position, index, subindex, data, complete)

    def object_info(self, position: int, index: int) -> ObjectInfo:
        """One object and its entries by SDO Information."""
        d = self._call(self.master.object_description, position, index)
        entries = []
        for sub in range(d.max_subindex + 1):
            try:
                e = self._call(self.master.entry_description, position, index, sub)
            except SdoAbort:
                continue  # a gap in an array/record
            entries.append(EntryInfo(sub, e.data_type, e.bit_length, e.access, e.name))
        return ObjectInfo(d.index, d.object_code, d.data_type, d.max_subindex, d.name, tuple(entries))

    def object_dictionary(self, position: int) -> list[ObjectInfo]:
        """Every object of the slave's dictionary by SDO Information (OD list, then descriptions)."""
        return [self.object_info(position, i) for i in self._call(self.master.od_list, position)]

    def foe_read(self, position: int, name: str, password: int = 0, *, progress: ProgressFn | None = None) -> bytes:
        """Read a file by FoE; FoeError carries the slave's FoE error code."""
        self.master.slave(position)
        return self._mbx.foe_read(position, name, password, progress)

    def foe_write(self, position: int, name: str, data: bytes, password: int = 0, *,
                  progress: ProgressFn | None = None) -> None:
        """Write a file by FoE (BUSY answers repeat the packet); FoeError carries the slave's code."""
        self.master.slave(position)
        self._mbx.foe_write(position, name, data, password, progress)

    def sii_read(self, position: int) -> bytes:
        """The SII EEPROM image up to its END category."""
        return bytes(self._call(self.master.read_sii, self.master.slave(position).station))

    def reg_read(self, position: int, address: int, length: int) -> bytes:
        """ESC registers by configured-address read (FPRD), IgH's ``reg_read``; MasterTimeout unanswered."""
        self.master.slave(position)
        return register_read(_MasterRegisters(self.master), position, address, length)

    def reg_write(self, position: int, address: int, data: bytes) -> None:
        """ESC registers by configured-address write (FPWR), IgH's ``reg_write``."""
        self.master.slave(position)
        register_write(_MasterRegisters(self.master), position, address, data)

    def sii_info(self, position: int) -> SiiInfo:
        """The parsed SII the scan read (identity, mailboxes, SyncManagers)."""
        return self.master.slave(position).sii

    def config_map(self) -> int:
        """PDO assignment by SDO -> SM2/SM3 and FMMUs; returns the process image size (no state change)."""
        size = int(self._call(self.master.config_map))
        self._mapped = True
        return size

    def configure_dc(self, position: int, cycle_ns: int, shift_ns: int = 0) -> None:
        """SYNC0 every ``cycle_ns`` (0 switches it off), first pulse on a cycle boundary + ``shift_ns``."""
        m = self.master
        station = m.slave(position).station
        if cycle_ns <= 0:
            self._call(m.fpwr, station, REG_DC_ACTIVATION, b"\x00")
            return
        now = U64.unpack(self._call(m.fprd, station, REG_DC_SYSTEM_TIME, 8))[0]
        start = now + round(DC_START_DELAY * 1e9)
        start = (start // cycle_ns + 1) * cycle_ns + shift_ns
        self._call(m.fpwr, station, REG_DC_ACTIVATION, b"\x00")
        self._call(m.fpwr, station, REG_DC_SYNC0_CYCLE, U32.pack(cycle_ns))
        self._call(m.fpwr, station, REG_DC_START_TIME, U64.pack(start))
        self._call(m.fpwr, station, REG_DC_ACTIVATION, b"\x03")

    def outputs(self, position: int) -> memoryview:
        """The slave's RxPDO bytes in the image: write them, the next :meth:`exchange` sends them."""
        s = self.master.slave(position)
        if not self._mapped:
            raise MasterError("config_map first")
        return memoryview(self.master.image)[s.output_offset:s.output_offset + s.output_bytes]

    def inputs(self, position: int) -> bytes:
        """The slave's TxPDO bytes as the last :meth:`exchange` brought them."""
        s = self.master.slave(position)
        if not self._mapped:
            raise MasterError("config_map first")
        return bytes(self.master.image[s.input_offset:s.input_offset + s.input_bytes])

    def exchange(self) -> tuple[int, int]:
        """One process-data cycle (LRW); returns (working counter, expected) and counts mismatches."""
        wkc = int(self.master.exchange_process_data())
        expected = self.master.expected_wkc
        self.last_wkc = wkc
        if wkc != expected:
            self.wkc_errors += 1
        return wkc, expected

    def close(self) -> None:
        """Stop a cycle the master may run; the segment stays with its owner (the rig)."""
        self.master.stop_cyclic()


def __getattr__(name: str) -> Any:
    """``from gatewaylab.hosts.ethercat.backend import PysoemBackend`` keeps working: the class lives in
    ``wire_backend`` (the I/O adapter), imported on first use so that neither module needs the
    other at import time."""
    if name == "PysoemBackend":
        from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend
        return PysoemBackend
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
