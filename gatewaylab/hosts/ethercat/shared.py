"""What both :class:`~gatewaylab.hosts.ethercat.backend.MasterBackend` implementations share.

The in-process backend (``inprocess.py``) and the SOEM one (``pysoem_backend.py``) reach a slave
in different ways but wait, poll and talk FoE the same way: the polling periods and attempt counts,
register access with its bounds check (:func:`register_read`, :func:`register_write` over a
:class:`Registers`), the one AL state wait (:func:`await_state`, :func:`state_of`) and FoE through
the slave's mailbox SyncManagers with plain register reads and writes (:class:`MailboxPort`), so
both report the slave's FoE error code and progress; SOEM's own FoE functions drop the error code.
The master's configuration (``config.py``) reads the SII until :func:`sii_complete` says it ends.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from typing import Protocol

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ProtocolError
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError, FoeError, FoeErrorCode, MailboxError, MasterError
from gatewaylab.ethercat.esc import REG_SM, AlState
from gatewaylab.ethercat.foe import FOE_HEADER, FoeOpcode, foe_packet
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, decode_mailbox, encode_mailbox
from gatewaylab.ethercat.sii import CATEGORY_HEADER, Category
from gatewaylab.hosts.ethercat.backend import MasterTimeout, ProgressFn

__all__ = ["AL_ERROR", "DC_START_DELAY", "FOE_BUSY_RETRY", "FOE_BUSY_TIMEOUT", "FOE_CODE_SUFFIX", "INFO_ATTEMPTS",
           "POLL", "REGISTER_ATTEMPTS", "RETRY_SETTLE", "SCAN_ATTEMPTS", "SCAN_RETRY", "SM_REG", "STATES",
           "STATE_POLL", "U16", "U32", "U64", "MailboxPort", "Registers", "StatePolled", "al_status_name",
           "await_state", "register_read", "register_write", "sii_complete", "state_of"]

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


#: The AL state values a status register may hold in its low nibble.
STATES = frozenset(int(s) for s in AlState)


class StatePolled(Protocol):
    """What :func:`await_state` needs of a backend: its clock, AL status and a process data cycle."""

    clock: Clock

    def al_status(self, position: int) -> tuple[int, int]: ...
    def exchange(self) -> tuple[int, int]: ...


def await_state(backend: StatePolled, pos: int, state: AlState, timeout: float, *, exchanging: bool) -> None:
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


def state_of(status: int) -> AlState:
    """The AL state in an AL status register value; MasterTimeout when it holds none (slave lost?)."""
    try:
        return AlState(status & 0x0F)
    except ValueError:
        raise MasterTimeout(f"AL status 0x{status:02X} holds no state (slave lost?)") from None


# ---------------------------------------------------------------------------------------- FoE
class Registers(Protocol):
    """Register access of one backend: None / False when the slave did not answer (working counter 0)."""

    def read(self, position: int, address: int, length: int) -> bytes | None: ...
    def write(self, position: int, address: int, data: bytes) -> bool | None: ...   # None: answer lost


class MailboxPort:
    """FoE through a slave's mailbox SyncManagers with plain register access (ETG.1000.6 FoE).

    The mailbox areas are read from the SM0/SM1 registers, so the bootstrap mailbox is used in
    BOOT without further ado. ``counter`` gives the mailbox counter of each request (0 = 'not
    used', which never collides with the counters another stack keeps for the same slave)."""

    def __init__(self, clock: Clock, regs: Registers, timeout: float, counter: Callable[[int], int]) -> None:
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


def register_read(regs: Registers, position: int, address: int, length: int) -> bytes:
    """``length`` bytes of a slave's registers, or MasterTimeout naming them (both backends)."""
    if not 0 <= address <= 0xFFFF or not 1 <= length <= 0x10000 - address:
        raise MasterError(f"registers 0x{address:04X}+{length} are outside the ESC's 64 KiB")
    data = regs.read(position, address, length)
    if data is None:
        raise MasterTimeout(f"slave {position}: no answer reading {length} byte(s) at 0x{address:04X}")
    return bytes(data)


def register_write(regs: Registers, position: int, address: int, data: bytes) -> None:
    """Write a slave's registers, or MasterTimeout (the write was not acknowledged)."""
    if not 0 <= address <= 0xFFFF or not 1 <= len(data) <= 0x10000 - address:
        raise MasterError(f"registers 0x{address:04X}+{len(data)} are outside the ESC's 64 KiB")
    if not regs.write(position, address, data):
        raise MasterTimeout(f"slave {position}: writing {len(data)} byte(s) at 0x{address:04X} was not "
                            "acknowledged (working counter 0 or no answer)")
