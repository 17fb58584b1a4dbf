"""The AL state machine of the ESC (AL control / AL status, 0x0120-0x0135) and the SM watchdog.

The master requests a state in AL control; the firmware answers in AL status and AL status code
(IDX guide 4.2, tables 4-16..4-18). A request runs on the PDI side once the access that carried it
is over (the ESC raises :class:`~gatewaylab.ethercat.esc_events.AlControlRequested`), as SOES's
ESC_ALevent does: the legal transitions are checked here, the firmware (:class:`AlFirmware`) may
refuse one with an AL status code, and hears of every change. The SM watchdog (0x0400/0x0420) drops
an OP slave whose outputs stop arriving to SAFEOP with 0x001B; that and every other exit from OP the
firmware makes by itself deactivate the output SyncManager until the master changes the state again.
"""

from __future__ import annotations

from typing import Protocol

from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc_memory import EscMemory
from gatewaylab.ethercat.esc_registers import (
    AL_ACK,
    AL_ERROR,
    AL_TRANSITIONS,
    REG_AL_STATUS,
    REG_AL_STATUS_CODE,
    REG_SM,
    REG_WD_COUNTER_SM,
    REG_WD_DIVIDER,
    REG_WD_STATUS_SM,
    REG_WD_TIME_PDI,
    REG_WD_TIME_SM,
    SM_STATUS_FULL,
    U16,
    AlState,
)
from gatewaylab.ethercat.slave_faults import AlRefusal

__all__ = ["AL_PENDING", "AlFirmware", "AlStateMachine"]

#: What :meth:`AlFirmware.check_transition` returns for a transition the firmware completes later (a slave
#: stack's pending transition): AL status keeps the present state, without error, until the firmware calls
#: :meth:`AlStateMachine.complete` or :meth:`AlStateMachine.refuse`.
AL_PENDING = -1


_RANK = {AlState.INIT: 0, AlState.PREOP: 1, AlState.BOOT: 1, AlState.SAFEOP: 2, AlState.OP: 3}


class AlFirmware(Protocol):
    """The firmware's part in a state change (the slave behind the ESC)."""

    def check_transition(self, old: AlState, new: AlState) -> int:
        """0 to accept a legal transition the master requested, else the AL status code refusing it."""
        ...

    def state_changed(self, old: AlState, new: AlState, code: int) -> None:
        """The state changed (``code`` != 0 when the slave fell back by itself)."""
        ...


class AlStateMachine:
    """AL status of one ESC over the shared register memory, and the SM watchdog that can drop it."""

    __slots__ = ("_wd_timer", "clock", "firmware", "mem", "memory", "refusal")

    def __init__(self, clock: Clock, memory: EscMemory, firmware: AlFirmware) -> None:
        self.clock = clock
        self.memory = memory
        self.mem = memory.mem
        self.firmware = firmware
        self._wd_timer: TimerHandle | None = None
        #: a fault: the next requested transition (or one) is refused with its code (``slave_faults``)
        self.refusal: AlRefusal | None = None
        memory.wd_changed = self.watchdog_written

    def reset(self) -> None:
        """Power-on: INIT without error, watchdog divider and times at their defaults (100 ms)."""
        m = self.mem
        U16.pack_into(m, REG_AL_STATUS, AlState.INIT)
        U16.pack_into(m, REG_WD_DIVIDER, 2498)  # 100 us watchdog tick
        U16.pack_into(m, REG_WD_TIME_PDI, 1000)
        U16.pack_into(m, REG_WD_TIME_SM, 1000)  # 100 ms

    @property
    def status(self) -> int:
        """AL status (0x0130): state in bits 3..0, error indication in bit 4."""
        return int(U16.unpack_from(self.mem, REG_AL_STATUS)[0])

    @property
    def state(self) -> AlState:
        """The present state."""
        return AlState(self.status & 0x0F)

    @property
    def status_code(self) -> int:
        """AL status code (0x0134): why the last request was refused or the slave fell back."""
        return int(U16.unpack_from(self.mem, REG_AL_STATUS_CODE)[0])

    # ------------------------------------------------------------------ requests and changes
    def control(self, control: int) -> None:
        """Serve an AL control request (the value the master wrote to 0x0120)."""
        requested = control & 0x0F
        ack = bool(control & AL_ACK)
        status = self.status
        current = AlState(status & 0x0F)
        error = bool(status & AL_ERROR)
        try:
            target = AlState(requested)
        except ValueError:
            self._refuse(current, AlStatusCode.UNKNOWN_STATE)
            return
        if target == AlState.INIT:
            self.memory.release_unused_sms()
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
        refusal = self.refusal
        if refusal is not None and refusal.matches(current, target):
            self.refusal = None
            self._refuse(current, refusal.code)
            refusal.on_used()
            return
        code = self.firmware.check_transition(current, target)
        if code == AL_PENDING:
            return
        if code:
            self._refuse(current, code)
            return
        self._enter(current, target)

    def complete(self, target: AlState) -> None:
        """The firmware completes a pending transition (see :data:`AL_PENDING`)."""
        self._enter(self.state, target)

    def refuse(self, code: int) -> None:
        """The firmware gives up a pending transition: the present state with the error flag and ``code``."""
        self._refuse(self.state, code)

    def _enter(self, current: AlState, target: AlState) -> None:
        U16.pack_into(self.mem, REG_AL_STATUS, int(target))
        U16.pack_into(self.mem, REG_AL_STATUS_CODE, 0)
        self.memory.start_outputs()  # the master took the slave through a state change
        if target == AlState.OP:
            self._start_watchdog()
        else:
            self.stop_watchdog()
        if _RANK[target] < _RANK[current] and target == AlState.INIT:
            for i in range(self.memory.n_sm):
                self.mem[REG_SM + 8 * i + 5] &= ~SM_STATUS_FULL & 0xFF
        self.firmware.state_changed(current, target, 0)

    def force(self, state: AlState, code: int = 0) -> None:
        """The firmware changes state by itself (error: ``state`` + error flag + ``code``). Leaving OP
        with an error (SM watchdog, a device error) deactivates the output SyncManager until the
        master's next state change (:meth:`EscMemory.stop_outputs`); an OP -> SAFEOP the master
        requests keeps it running, as the slave stacks do."""
        old = self.state
        U16.pack_into(self.mem, REG_AL_STATUS, int(state) | (AL_ERROR if code else 0))
        U16.pack_into(self.mem, REG_AL_STATUS_CODE, code)
        if state != AlState.OP:
            self.stop_watchdog()
            if old == AlState.OP and code:
                self.memory.stop_outputs()  # a local exit from OP: outputs stop counting
        if old != state:
            self.firmware.state_changed(old, state, code)

    def _refuse(self, current: AlState, code: int) -> None:
        self.memory.stats.al_refusals += 1
        U16.pack_into(self.mem, REG_AL_STATUS, int(current) | AL_ERROR)
        U16.pack_into(self.mem, REG_AL_STATUS_CODE, code)

    # ------------------------------------------------------------------ SM watchdog
    def watchdog_time(self) -> float:
        """SM watchdog time in seconds: (divider + 2) * 40 ns * time (ET1100 0x0400/0x0420); 0 = off."""
        div: int = U16.unpack_from(self.mem, REG_WD_DIVIDER)[0]
        ticks: int = U16.unpack_from(self.mem, REG_WD_TIME_SM)[0]
        return (div + 2) * 40e-9 * ticks

    def _start_watchdog(self) -> None:
        self.stop_watchdog()
        period = self.watchdog_time()
        if period <= 0 or not self.memory.any_watchdog():
            return
        self.memory.wd_last = self.clock.now()
        self._wd_timer = self.clock.call_at(self.memory.wd_last + period, self._wd_check)

    def watchdog_written(self) -> None:
        """The master wrote the watchdog divider or time: in OP the count starts again with the new time
        (0: the watchdog stops), as the ET1100 restarts its counter from the registers."""
        if self.state == AlState.OP:
            self._start_watchdog()

    def stop_watchdog(self) -> None:
        """The watchdog stops watching (left OP, or powered off)."""
        if self._wd_timer is not None:
            self._wd_timer.cancel()
            self._wd_timer = None

    def _wd_check(self) -> None:
        self._wd_timer = None
        period = self.watchdog_time()
        if period <= 0 or self.state != AlState.OP:
            return
        due = self.memory.wd_last + period
        now = self.clock.now()
        if now < due:
            self._wd_timer = self.clock.call_at(due, self._wd_check)
            return
        self.memory.stats.watchdog_expiries += 1
        self.mem[REG_WD_STATUS_SM] = 0
        self.mem[REG_WD_COUNTER_SM] = min(0xFF, self.mem[REG_WD_COUNTER_SM] + 1)
        self.memory.watchdog_expired()  # digital outputs on 0x0F00 go to 0
        self.force(AlState.SAFEOP, AlStatusCode.SM_WATCHDOG)
