"""EtherCAT faults of one slave: its AL state machine, its mailbox, its EEPROM (docs/faults.md).

The mechanisms live in :mod:`gatewaylab.ethercat.slave_faults` (armed on the slave, consulted only where
they bite: an AL request, a mailbox message, an SII command); this mixin finds the device, arms the fault
under ``clock.lock`` and puts it on the fault board while it is in force: ``ec-al-error``, ``ec-sdo-abort``,
``ec-sdo-silent``, ``ec-foe-error`` and ``ec-mailbox-lose`` until used (or ``ec-clear``), ``ec-eeprom``
until its ``seconds`` or ``ec-clear``. ``ec-drop-state`` and ``ec-emcy`` happen at once (the slave's AL
status, resp. the master's mailbox, then holds what a master must deal with).
"""

from __future__ import annotations

import struct
from typing import Any

from gatewaylab.ethercat.errors import AlStatusCode, EtherCATConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave
from gatewaylab.ethercat.slave_faults import (
    AlRefusal,
    FoeFailure,
    MailboxFaults,
    SdoAbortFault,
    SdoSilence,
    SiiHold,
    parse_transition,
    transition_name,
)
from gatewaylab.rig.faults_core import FaultRefused, FaultsCore, check_count, check_seconds

__all__ = ["EC_SLAVE_REQUESTS", "EEPROM_FAULTS", "EcSlaveFaults"]

#: ``ec-eeprom`` faults (``product=0xNNNN`` besides)
EEPROM_FAULTS = ("busy", "checksum", "stuck")
#: the SII word holding the product code (ETG.2010: words 0x0A-0x0B), as a byte offset
_PRODUCT_AT = 2 * 0x0A
_U32 = struct.Struct("<I")
#: AL status code of a drop to each state when none is given (ETG.1000.6 AL status codes)
_DROP_CODE = {AlState.SAFEOP: AlStatusCode.SM_WATCHDOG, AlState.PREOP: 0x0001}
_ORDER = (AlState.INIT, AlState.PREOP, AlState.SAFEOP, AlState.OP)


def _code16(what: str, code: int) -> None:
    if not 0 < code <= 0xFFFF:
        raise FaultRefused(f"{what} 0x{code:X} is out of range (0x0001..0xFFFF)")


class EcSlaveFaults(FaultsCore):
    """``ec-al-error``, ``ec-drop-state``, ``ec-sdo-abort``, ``ec-sdo-silent``, ``ec-foe-error``,
    ``ec-mailbox-lose``, ``ec-emcy``, ``ec-eeprom``."""

    def _slave(self, device: str) -> Slave:
        segment, position = self.ethercat_position(device)
        slave = segment.slaves[position]
        if position in segment.unplugged:
            raise FaultRefused(f"{device} is unplugged")
        return slave

    def _mailbox(self, device: str, protocol: str) -> tuple[Slave, MailboxFaults]:
        slave = self._slave(device)
        served = slave.desc.coe if protocol == "CoE" else slave.desc.foe
        if not served:
            raise FaultRefused(f"{device} has no {protocol} mailbox")
        faults = slave.mailbox_faults
        if faults is None:
            faults = slave.mailbox_faults = MailboxFaults()
        return slave, faults

    def _board(self, fault: str, device: str, details: dict[str, Any], undo: Any,
               seconds: float | None = None) -> dict[str, Any]:
        """Put it on the board; the answer (details with the id)."""
        entry = self.activate(fault, device, details, undo, seconds)
        return {"device": device, **entry.as_json()}

    @staticmethod
    def _tidy(slave: Slave) -> None:
        faults = slave.mailbox_faults
        if faults is not None and faults.empty():
            slave.mailbox_faults = None

    # -- AL state machine -----------------------------------------------------------------------------
    def ec_al_error(self, device: str, code: int, on: str | None = None) -> dict[str, Any]:
        """The slave refuses the next transition the master requests (only ``on``: ``PS``, ``SO``,
        ``PREOP-SAFEOP`` ...) with AL status ``code``, error flag latched until the master acknowledges."""
        _code16("AL status code", code)
        try:
            transition = None if on is None else parse_transition(on)
        except EtherCATConfigError as exc:
            raise FaultRefused(str(exc)) from None

        def act() -> dict[str, Any]:
            al = self._slave(device).esc.al
            if al.refusal is not None:
                raise FaultRefused(f"{device} already refuses a transition (ec-clear {device} first)")
            refusal = AlRefusal(code, transition)
            details = {"code": code, "on": "any" if transition is None else transition_name(transition)}

            def undo() -> None:
                if al.refusal is refusal:
                    al.refusal = None
            answer = self._board("ec-al-error", device, details, undo)
            refusal.on_used = lambda: self.finish(answer["id"])
            al.refusal = refusal
            return answer
        return self.locked(act)

    def ec_drop_state(self, device: str, state: str, code: int | None = None) -> dict[str, Any]:
        """The slave leaves its state by itself: SAFEOP or PREOP with the error flag and ``code``
        (default 0x001B for SAFEOP, 0x0001 for PREOP); INIT without a code is a power glitch (the ESC
        resets: station address, SyncManagers, FMMUs, DC lost, AL status INIT), INIT with a code a
        firmware error (INIT + error flag + code, registers kept)."""
        try:
            target = AlState[state.upper()]
        except KeyError:
            raise FaultRefused(f"state {state!r}: INIT, PREOP or SAFEOP") from None
        if target not in (AlState.INIT, AlState.PREOP, AlState.SAFEOP):
            raise FaultRefused(f"state {state!r}: INIT, PREOP or SAFEOP")
        if code is not None:
            _code16("AL status code", code)

        def act() -> dict[str, Any]:
            esc = self._slave(device).esc
            old = esc.al_state
            if target == AlState.INIT and code is None:
                esc.power_cycle()
                return {"fault": "ec-drop-state", "device": device, "from": old.name, "state": "INIT",
                        "reset": True, "al_status": esc.al_status}
            if old not in _ORDER or _ORDER.index(old) <= _ORDER.index(target):
                raise FaultRefused(f"{device} is in {old.name}: it can only drop below it")
            value = code if code is not None else _DROP_CODE.get(target, 0x0001)
            esc.force_state(target, value)
            return {"fault": "ec-drop-state", "device": device, "from": old.name, "state": target.name,
                    "code": value, "al_status": esc.al_status}
        return self.locked(act)

    # -- mailbox -------------------------------------------------------------------------------------
    def ec_sdo_abort(self, device: str, code: int, index: int | None = None,
                     segment: int | None = None) -> dict[str, Any]:
        """The next SDO request (to ``index`` only) is answered with abort ``code``; with ``segment`` K its
        transfer's K-th segment request is."""
        if not 0 < code <= 0xFFFFFFFF:
            raise FaultRefused(f"abort code 0x{code:X} is out of range (32 bits)")
        if index is not None and not 0 <= index <= 0xFFFF:
            raise FaultRefused(f"index 0x{index:X} is out of range")
        if segment is not None:
            check_count("segment", segment)

        def act() -> dict[str, Any]:
            slave, faults = self._mailbox(device, "CoE")
            fault = SdoAbortFault(code, index, segment)
            details: dict[str, Any] = {"abort_code": code}
            if index is not None:
                details["index"] = index
            if segment is not None:
                details["segment"] = segment

            def undo() -> None:
                if faults.sdo_abort is fault:
                    faults.sdo_abort = None
                self._tidy(slave)
            answer = self._board("ec-sdo-abort", device, details, undo)
            fault.on_used = lambda: self.finish(answer["id"])
            old = faults.sdo_abort
            faults.sdo_abort = fault
            if old is not None:
                old.on_used()           # replaced: the earlier one ends
            return answer
        return self.locked(act)

    def ec_sdo_silent(self, device: str, n: int = 1) -> dict[str, Any]:
        """The next ``n`` SDO requests get no answer (the master's SDO timeout)."""
        check_count("n", n)

        def act() -> dict[str, Any]:
            slave, faults = self._mailbox(device, "CoE")
            if faults.sdo_silence is not None:
                raise FaultRefused(f"{device} is silent already (ec-clear {device} first)")
            fault = SdoSilence(n)
            details = {"n": n}

            def undo() -> None:
                if faults.sdo_silence is fault:
                    faults.sdo_silence = None
                self._tidy(slave)
            answer = self._board("ec-sdo-silent", device, details, undo)
            fault.on_used = lambda: self.finish(answer["id"])
            faults.sdo_silence = fault
            return answer
        return self.locked(act)

    def ec_foe_error(self, device: str, code: int, packet: int) -> dict[str, Any]:
        """The next FoE transfer fails at data packet ``packet`` with FoE error ``code``."""
        if not 0 <= code <= 0xFFFFFFFF:
            raise FaultRefused(f"FoE error code 0x{code:X} is out of range (32 bits)")
        check_count("packet", packet)

        def act() -> dict[str, Any]:
            slave, faults = self._mailbox(device, "FoE")
            if faults.foe_failure is not None:
                raise FaultRefused(f"{device} already fails an FoE transfer (ec-clear {device} first)")
            fault = FoeFailure(code, packet)
            details = {"error_code": code, "packet": packet}

            def undo() -> None:
                if faults.foe_failure is fault:
                    faults.foe_failure = None
                self._tidy(slave)
            answer = self._board("ec-foe-error", device, details, undo)
            fault.on_used = lambda: self.finish(answer["id"])
            faults.foe_failure = fault
            return answer
        return self.locked(act)

    def ec_mailbox_lose(self, device: str) -> dict[str, Any]:
        """The next mailbox reply the master reads is lost once: the master's repeat request (SM1
        0x0806 bit 1) must get it back."""
        def act() -> dict[str, Any]:
            slave, faults = self._mailbox(device, "CoE")
            if faults.lose_reply is not None:
                raise FaultRefused(f"{device} loses a reply already")
            marker: list[int] = []

            def used() -> None:
                self.finish(marker[0])

            def undo() -> None:
                if faults.lose_reply is used:
                    faults.lose_reply = None
                self._tidy(slave)
            answer = self._board("ec-mailbox-lose", device, {}, undo)
            marker.append(answer["id"])
            faults.lose_reply = used
            return answer
        return self.locked(act)

    def ec_emcy(self, device: str, code: int, register: int = 0, data: str = "") -> dict[str, Any]:
        """The slave sends a CoE emergency (ETG.1000.6: CoE service 1, error code, error register, 5
        data bytes given as hex)."""
        if not 0 <= code <= 0xFFFF:
            raise FaultRefused(f"emergency error code 0x{code:X} is out of range (16 bits)")
        if not 0 <= register <= 0xFF:
            raise FaultRefused(f"error register 0x{register:X} is out of range (8 bits)")
        try:
            raw = bytes.fromhex(data)
        except ValueError:
            raise FaultRefused(f"data {data!r} is not hex bytes") from None
        if len(raw) > 5:
            raise FaultRefused("an emergency carries 5 data bytes at most")

        def act() -> dict[str, Any]:
            slave, _faults = self._mailbox(device, "CoE")
            self._tidy(slave)
            if slave.state == AlState.INIT:
                raise FaultRefused(f"{device} is in INIT: its mailbox is not running")
            slave.emergency(code, register, raw)
            return {"fault": "ec-emcy", "device": device, "error_code": code, "register": register,
                    "data": raw.ljust(5, b"\0").hex()}
        return self.locked(act)

    # -- EEPROM ---------------------------------------------------------------------------------------
    def ec_eeprom(self, device: str, kind: str, seconds: float | None = None) -> dict[str, Any]:
        """The EEPROM interface is ``busy`` (0x0502 bit 15; the waiting command runs when it ends), a
        read is ``stuck`` (never completes; fails when the fault ends), the SII has a ``checksum`` error
        (word 7 wrong, 0x0502 bit 11), or holds ``product=0xNNNN`` (a wrong device in the line)."""
        if seconds is not None:
            check_seconds("seconds", seconds)
        product: int | None = None
        if kind.startswith("product="):
            try:
                product = int(kind.split("=", 1)[1], 0)
            except ValueError:
                raise FaultRefused(f"{kind!r}: product=0xNNNN") from None
            if not 0 <= product <= 0xFFFFFFFF:
                raise FaultRefused(f"product code 0x{product:X} is out of range (32 bits)")
        elif kind not in EEPROM_FAULTS:
            raise FaultRefused(f"ec-eeprom {kind!r}: one of {', '.join(EEPROM_FAULTS)}, product=0xNNNN")
        if kind == "busy" and seconds is None:
            seconds = 1.0

        def act() -> dict[str, Any]:
            sii = self._slave(device).esc.sii
            if any(e.fault == "ec-eeprom" and e.target == device for e in self.board.entries()):
                raise FaultRefused(f"{device} has an EEPROM fault already (ec-clear {device} first)")
            details: dict[str, Any] = {"kind": kind}
            if kind in ("busy", "stuck"):
                hold = SiiHold(kind)
                sii.start_hold(hold)

                def undo() -> None:
                    if sii.hold is hold:
                        sii.end_hold()
            else:
                at, size = (14, 1) if product is None else (_PRODUCT_AT, 4)
                saved = bytes(sii.eeprom[at:at + size])
                if product is None:
                    sii.eeprom[at] ^= 0xFF          # the checksum of words 0..6 no longer holds
                    sii.reload()
                else:
                    details["product"] = product
                    details["was"] = _U32.unpack(saved)[0]
                    _U32.pack_into(sii.eeprom, at, product)

                def undo() -> None:
                    sii.eeprom[at:at + size] = saved
                    if product is None:
                        sii.reload()
            return self._board("ec-eeprom", device, details, undo, seconds)
        return self.locked(act)


_R, _O = True, False

#: fault name -> (method, {argument: (JSON type, required)}), rows of rig/faults.py's ``REQUESTS``
EC_SLAVE_REQUESTS: dict[str, tuple[str, dict[str, tuple[str, bool]]]] = {
    "ec-al-error": ("ec_al_error", {"device": ("string", _R), "code": ("int", _R), "on": ("string", _O)}),
    "ec-drop-state": ("ec_drop_state", {"device": ("string", _R), "state": ("string", _R), "code": ("int", _O)}),
    "ec-sdo-abort": ("ec_sdo_abort", {"device": ("string", _R), "code": ("int", _R), "index": ("int", _O),
                                      "segment": ("int", _O)}),
    "ec-sdo-silent": ("ec_sdo_silent", {"device": ("string", _R), "n": ("int", _O)}),
    "ec-foe-error": ("ec_foe_error", {"device": ("string", _R), "code": ("int", _R), "packet": ("int", _R)}),
    "ec-mailbox-lose": ("ec_mailbox_lose", {"device": ("string", _R)}),
    "ec-emcy": ("ec_emcy", {"device": ("string", _R), "code": ("int", _R), "register": ("int", _O),
                            "data": ("string", _O)}),
    "ec-eeprom": ("ec_eeprom", {"device": ("string", _R), "kind": ("string", _R), "seconds": ("number", _O)}),
}
