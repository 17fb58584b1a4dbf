"""Faults a single slave can have on its own: an AL transition refused, mailbox replies that abort, stay
silent, fail or get lost, and an EEPROM interface that is busy, stuck or holds the wrong data.

Sans-I/O, no clock: each fault is an object armed on one slave (:class:`AlRefusal` on the ESC's AL state
machine, :class:`MailboxFaults` on the :class:`~gatewaylab.ethercat.slave.Slave`, :class:`SiiHold` on the
ESC's EEPROM interface) that the slave consults only where the fault can bite -- an AL control request, a
mailbox message, an SII command -- never per frame. ``on_used`` tells whoever armed it (the rig's fault
board) that a fault of limited count is used up. The rig's glue is ``gatewaylab/rig/faults_ec_slave.py``.

Sources: ETG.1000.6 AL state machine (transitions IP, PS, SO ..., AL status error flag 0x0130 bit 4, AL
status code 0x0134), CoE SDO abort (ETG.1000.6 SDO abort transfer, codes as CiA 301), FoE error request
(ETG.1000.6 FoE: opcode 5, error code, text), the mailbox repeat (ETG.1000.4 / ET1100 0x0806 bit 1), the
ET1100 EEPROM interface (0x0502 busy bit 15, checksum error bit 11, acknowledge error bit 13).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Final

from gatewaylab.ethercat.coe import COE_HEADER, CoeServer, CoeService, abort_message
from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.ethercat.esc_registers import AlState
from gatewaylab.ethercat.foe import FOE_HEADER, FoeOpcode, FoeServer, foe_packet

__all__ = ["AlRefusal", "FoeFailure", "MailboxFaults", "SdoAbortFault", "SdoSilence", "SiiHold",
           "parse_transition", "transition_name"]

_SDO: Final = struct.Struct("<BHB")     # command, index, subindex (after the CoE header)
#: ETG.1000.6 names the transitions by the states' initials (IP, PS, SO, OS, ...)
_INITIAL: Final = {"I": AlState.INIT, "P": AlState.PREOP, "S": AlState.SAFEOP, "O": AlState.OP, "B": AlState.BOOT}
_NAMES: Final = {s.name: s for s in _INITIAL.values()}


def _nothing() -> None:
    pass


def parse_transition(text: str) -> tuple[AlState, AlState]:
    """An AL state transition as ETG.1000.6 names it (``PS``, ``SO``, ``IP`` ...) or by its states
    (``PREOP-SAFEOP``, ``SAFEOP>OP``), case-insensitive; EtherCATConfigError for anything else."""
    t = text.strip().upper()
    if len(t) == 2 and t[0] in _INITIAL and t[1] in _INITIAL and t[0] != t[1]:
        return _INITIAL[t[0]], _INITIAL[t[1]]
    for sep in ("-", ">", "_TO_"):
        a, found, b = t.partition(sep)
        if found and a in _NAMES and b in _NAMES and a != b:
            return _NAMES[a], _NAMES[b]
    raise EtherCATConfigError(f"not an AL transition: {text!r} (e.g. PS, SO, PREOP-SAFEOP)")


def transition_name(transition: tuple[AlState, AlState]) -> str:
    """``PREOP-SAFEOP`` for (PREOP, SAFEOP)."""
    return f"{transition[0].name}-{transition[1].name}"


class AlRefusal:
    """The slave refuses the next transition the master requests (only ``transition`` when given) with
    AL status ``code`` and the error flag set; the master's error acknowledge clears it."""

    __slots__ = ("code", "on_used", "transition")

    def __init__(self, code: int, transition: tuple[AlState, AlState] | None = None,
                 on_used: Callable[[], None] = _nothing) -> None:
        self.code = code
        self.transition = transition
        self.on_used = on_used

    def matches(self, old: AlState, new: AlState) -> bool:
        """This request is the one to refuse."""
        return self.transition is None or self.transition == (old, new)


class SdoAbortFault:
    """The next SDO request (to ``index`` only, when given) is answered with abort ``code``; with
    ``segment`` K the transfer starts normally and its K-th segment request is aborted instead."""

    __slots__ = ("_segments", "_transfer", "code", "index", "on_used", "segment")

    def __init__(self, code: int, index: int | None = None, segment: int | None = None,
                 on_used: Callable[[], None] = _nothing) -> None:
        self.code = code
        self.index = index
        self.segment = segment
        self.on_used = on_used
        self._transfer: tuple[int, int] | None = None
        self._segments = 0


class SdoSilence:
    """The next ``left`` SDO requests get no answer at all (the master's SDO timeout)."""

    __slots__ = ("left", "on_used")

    def __init__(self, left: int, on_used: Callable[[], None] = _nothing) -> None:
        self.left = left
        self.on_used = on_used


class FoeFailure:
    """An FoE transfer fails at packet ``packet`` with FoE error ``code``: a write when the master sends
    data packet K, a read when the slave would send it."""

    __slots__ = ("code", "on_used", "packet")

    def __init__(self, code: int, packet: int, on_used: Callable[[], None] = _nothing) -> None:
        self.code = code
        self.packet = packet
        self.on_used = on_used


class MailboxFaults:
    """The mailbox faults armed on one slave; the slave consults it for every CoE and FoE message and
    every read of its send mailbox while it is set (``Slave.mailbox_faults``)."""

    __slots__ = ("foe_failure", "lose_reply", "sdo_abort", "sdo_silence")

    def __init__(self) -> None:
        self.sdo_abort: SdoAbortFault | None = None
        self.sdo_silence: SdoSilence | None = None
        self.foe_failure: FoeFailure | None = None
        #: the next reply the master reads is lost once (called when it is)
        self.lose_reply: Callable[[], None] | None = None

    def empty(self) -> bool:
        """Nothing armed."""
        return (self.sdo_abort is None and self.sdo_silence is None and self.foe_failure is None
                and self.lose_reply is None)

    def take_lost_reply(self) -> bool:
        """The master read the send mailbox: True when this reply is the one to lose (used up then)."""
        used = self.lose_reply
        if used is None:
            return False
        self.lose_reply = None
        used()
        return True

    def coe(self, data: bytes, server: CoeServer) -> list[bytes] | None:
        """The replies to a CoE message when a fault takes it, else None (the server serves it)."""
        if len(data) < 2 + _SDO.size or COE_HEADER.unpack_from(data, 0)[0] >> 12 != CoeService.SDO_REQUEST:
            return None
        silence = self.sdo_silence
        if silence is not None:
            silence.left -= 1
            if silence.left <= 0:
                self.sdo_silence = None
                silence.on_used()
            return []
        fault = self.sdo_abort
        if fault is None:
            return None
        cmd, index, sub = _SDO.unpack_from(data, 2)
        ccs = cmd >> 5
        if ccs in (1, 2):                       # initiate download / upload (complete access too)
            fault._transfer = None
            if fault.index is not None and index != fault.index:
                return None
            if fault.segment is None:
                return self._abort(fault, server, index, sub)
            fault._transfer = (index, sub)
            fault._segments = 0
            return None
        if ccs in (0, 3) and fault._transfer is not None:   # a segment of the watched transfer
            fault._segments += 1
            if fault._segments >= (fault.segment or 1):
                return self._abort(fault, server, *fault._transfer)
        return None

    def _abort(self, fault: SdoAbortFault, server: CoeServer, index: int, sub: int) -> list[bytes]:
        self.sdo_abort = None
        server.cancel()
        server.aborts_sent += 1
        fault.on_used()
        return [abort_message(index, sub, fault.code)]

    def foe(self, data: bytes, server: FoeServer) -> list[bytes]:
        """The replies to an FoE message: the server's, unless the armed failure hits this packet."""
        fault = self.foe_failure
        if fault is None or len(data) < FOE_HEADER.size:
            return server.handle(data)
        opcode, _res, word = FOE_HEADER.unpack_from(data, 0)
        if opcode == FoeOpcode.DATA and word == fault.packet:      # a write: the master's packet K
            return self._fail(fault, server)
        replies = server.handle(data)
        for reply in replies:                                       # a read: the slave's packet K
            if len(reply) >= FOE_HEADER.size:
                op, _r, number = FOE_HEADER.unpack_from(reply, 0)
                if op == FoeOpcode.DATA and number == fault.packet:
                    return self._fail(fault, server)
        return replies

    def _fail(self, fault: FoeFailure, server: FoeServer) -> list[bytes]:
        self.foe_failure = None
        server.reset()
        server.errors_sent += 1
        fault.on_used()
        return [foe_packet(FoeOpcode.ERR, fault.code)]


class SiiHold:
    """The EEPROM interface held by a fault (``SiiInterface.hold``): ``busy`` -- every command waits with
    the busy bit set until the hold ends, then the first one runs; ``stuck`` -- the next read never
    completes (busy until the hold ends, then it fails with the acknowledge error)."""

    __slots__ = ("held", "mode")

    def __init__(self, mode: str) -> None:
        if mode not in ("busy", "stuck"):
            raise EtherCATConfigError(f"SII hold {mode!r}: busy or stuck")
        self.mode = mode
        #: the control word of the command waiting (0: none)
        self.held = 0

    def takes(self, command: int) -> bool:
        """This command (0x0502 bits 8..10) waits: every one when busy, a read when stuck; the first
        waiting command stays the one (the ESC ignores 0x0502 writes while busy)."""
        return command != 0 and (self.mode == "busy" or command == 1 or self.held != 0)
