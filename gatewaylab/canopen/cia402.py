"""CiA 402 power drive state machine (PDS FSA) as an Enum transition table.

Pure logic: controlword in -> (new state, transition number); statusword bits out. The drive
(:mod:`gatewaylab.devices.canopen_drive.device`) decides what a transition does to the power stage and the motion.
Numbers and bit patterns follow CiA 402 V4.0 (IEC 61800-7-201), referenced by the IDX guide 3.1.
"""

from __future__ import annotations

from enum import Enum, IntEnum, IntFlag

__all__ = [
    "CONTROLWORD_NEXT",
    "STATE_BITS",
    "STATE_MASK",
    "SUPPORTED_MODES",
    "TRANSITIONS",
    "Command",
    "Cw",
    "OpMode",
    "PdsState",
    "Sw",
    "decode_command",
    "next_state",
    "state_from_statusword",
]


class PdsState(Enum):
    """The eight states of the CiA 402 power drive system FSA."""

    # Members are singletons compared by identity: hash them by identity too (C speed), the
    # drive looks them up in its tables at 1 kHz.
    __hash__ = object.__hash__

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"


class Command(Enum):
    """Device control commands encoded in controlword bits 0-3 and 7 (CiA 402 table 'commands')."""

    __hash__ = object.__hash__

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"
    SWITCH_ON_ENABLE = "switch on + enable operation"
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    DISABLE_OPERATION = "disable operation"
    ENABLE_OPERATION = "enable operation"
    FAULT_RESET = "fault reset"


class Cw(IntFlag):
    """Controlword 0x6040 bits (CiA 402)."""

    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2          # active low: 0 = quick stop requested
    ENABLE_OPERATION = 1 << 3
    NEW_SETPOINT = 1 << 4        # PP; homing: start homing operation
    CHANGE_IMMEDIATELY = 1 << 5  # PP
    RELATIVE = 1 << 6            # PP
    FAULT_RESET = 1 << 7
    HALT = 1 << 8


class Sw(IntFlag):
    """Statusword 0x6041 bits (CiA 402; bit 9 'remote' per IDX guide table 3-11)."""

    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5          # active low: 0 = quick stop active
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    INTERNAL_LIMIT = 1 << 11
    OP_SPECIFIC_12 = 1 << 12     # PP: set-point acknowledge; PV: speed; homing: attained;
    #                              CSP/CSV/CST: target value ignored (drive follows)
    OP_SPECIFIC_13 = 1 << 13     # PP/CSP: following error; homing: homing error


class OpMode(IntEnum):
    """Modes of operation 0x6060/0x6061 the drive supports (CiA 402)."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    PROFILE_VELOCITY = 3
    HOMING = 6
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10


#: 0x6502 supported drive modes: bit (mode - 1) for every supported mode (CiA 402).
SUPPORTED_MODES = sum(1 << (m - 1) for m in OpMode if m > 0)

#: State -> statusword bits 0-6 (bit 4 'voltage enabled' set while the power stage has voltage).
STATE_BITS: dict[PdsState, int] = {
    PdsState.NOT_READY_TO_SWITCH_ON: 0x0000,
    PdsState.SWITCH_ON_DISABLED: 0x0040,
    PdsState.READY_TO_SWITCH_ON: 0x0031,
    PdsState.SWITCHED_ON: 0x0033,
    PdsState.OPERATION_ENABLED: 0x0037,
    PdsState.QUICK_STOP_ACTIVE: 0x0017,
    PdsState.FAULT_REACTION_ACTIVE: 0x001F,
    PdsState.FAULT: 0x0018,
}
STATE_MASK = 0x007F

S = PdsState
C = Command
#: (state, command) -> (next state, CiA 402 transition number).
TRANSITIONS: dict[tuple[PdsState, Command], tuple[PdsState, int]] = {
    (S.SWITCH_ON_DISABLED, C.SHUTDOWN): (S.READY_TO_SWITCH_ON, 2),
    (S.READY_TO_SWITCH_ON, C.SWITCH_ON): (S.SWITCHED_ON, 3),
    (S.READY_TO_SWITCH_ON, C.SWITCH_ON_ENABLE): (S.OPERATION_ENABLED, 3),  # 3 then 4
    (S.SWITCHED_ON, C.ENABLE_OPERATION): (S.OPERATION_ENABLED, 4),
    (S.SWITCHED_ON, C.SWITCH_ON_ENABLE): (S.OPERATION_ENABLED, 4),
    (S.OPERATION_ENABLED, C.DISABLE_OPERATION): (S.SWITCHED_ON, 5),
    (S.SWITCHED_ON, C.SHUTDOWN): (S.READY_TO_SWITCH_ON, 6),
    (S.READY_TO_SWITCH_ON, C.DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 7),
    (S.READY_TO_SWITCH_ON, C.QUICK_STOP): (S.SWITCH_ON_DISABLED, 7),
    (S.OPERATION_ENABLED, C.SHUTDOWN): (S.READY_TO_SWITCH_ON, 8),
    (S.OPERATION_ENABLED, C.DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 9),
    (S.SWITCHED_ON, C.DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 10),
    (S.SWITCHED_ON, C.QUICK_STOP): (S.SWITCH_ON_DISABLED, 10),
    (S.OPERATION_ENABLED, C.QUICK_STOP): (S.QUICK_STOP_ACTIVE, 11),
    (S.QUICK_STOP_ACTIVE, C.DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 12),
    (S.FAULT, C.FAULT_RESET): (S.SWITCH_ON_DISABLED, 15),
    (S.QUICK_STOP_ACTIVE, C.ENABLE_OPERATION): (S.OPERATION_ENABLED, 16),
    (S.QUICK_STOP_ACTIVE, C.SWITCH_ON_ENABLE): (S.OPERATION_ENABLED, 16),
}
del S, C


def decode_command(controlword: int, previous: int) -> Command | None:
    """The device control command in ``controlword`` (``previous`` detects the fault-reset edge).

    CiA 402 command coding (bits 7, 3, 2, 1, 0): shutdown 0xx110, switch on 0x0111,
    switch on + enable 0x1111, disable voltage 0xxx0x, quick stop 0xx01x, disable operation
    0x0111, enable operation 0x1111, fault reset 0->1 edge of bit 7.
    """
    if controlword & 0x80:                       # bit 7 fault reset
        return Command.FAULT_RESET if not previous & 0x80 else None
    low = controlword & 0x0F
    if not low & 0x02:                           # bit 1 enable voltage
        return Command.DISABLE_VOLTAGE
    if not low & 0x04:                           # bit 2 quick stop (active low)
        return Command.QUICK_STOP
    if low & 0x07 == 0x06:
        return Command.SHUTDOWN
    if low == 0x07:
        return Command.SWITCH_ON   # also 'disable operation' when in OPERATION ENABLED
    return Command.SWITCH_ON_ENABLE  # 0x0F: also 'enable operation'


def _lookup(state: PdsState, command: Command) -> tuple[PdsState, int] | None:
    hit = TRANSITIONS.get((state, command))
    if hit is not None:
        return hit
    if command is Command.SWITCH_ON:
        return TRANSITIONS.get((state, Command.DISABLE_OPERATION))
    if command is Command.SWITCH_ON_ENABLE:
        return TRANSITIONS.get((state, Command.ENABLE_OPERATION))
    return None


#: next_state for every (state, command), the 'switch on' / 'switch on + enable' codings that
#: mean 'disable operation' / 'enable operation' resolved in advance: one lookup per controlword.
_NEXT: dict[tuple[PdsState, Command], tuple[PdsState, int] | None] = {
    (state, command): _lookup(state, command) for state in PdsState for command in Command}


def next_state(state: PdsState, command: Command | None) -> tuple[PdsState, int] | None:
    """(new state, transition number) for a controlword command, or None (no transition)."""
    if command is None:
        return None
    return _NEXT[state, command]


def state_from_statusword(statusword: int) -> PdsState | None:
    """Decode a statusword with the CiA 402 masks (for masters and tests)."""
    for state, bits in STATE_BITS.items():
        mask = 0x4F if state in (PdsState.NOT_READY_TO_SWITCH_ON, PdsState.SWITCH_ON_DISABLED,
                                 PdsState.FAULT_REACTION_ACTIVE, PdsState.FAULT) else 0x6F
        if statusword & mask == bits & mask:
            return state
    return None


def _controlword_table(state: PdsState) -> tuple[tuple[PdsState, int] | None, ...]:
    table: list[tuple[PdsState, int] | None] = []
    for key in range(0x200):
        cw, prev = key & 0x8F, (key >> 1) & 0x80
        table.append(next_state(state, decode_command(cw, prev)))
    return tuple(table)


#: ``CONTROLWORD_NEXT[state][(cw & 0x8F) | ((previous & 0x80) << 1)]`` is
#: ``next_state(state, decode_command(cw, previous))``: the command depends only on controlword
#: bits 0-3 and 7 and on bit 7 of the previous controlword (fault-reset edge).
CONTROLWORD_NEXT: dict[PdsState, tuple[tuple[PdsState, int] | None, ...]] = {
    state: _controlword_table(state) for state in PdsState}
