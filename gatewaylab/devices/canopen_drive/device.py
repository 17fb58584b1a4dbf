"""The maxon IDX-like CiA 402 servo drive on the gatewaylab CANopen node stack.

``Drive(clock, bus, node_id, serial, name="", store_path=None)`` builds the object dictionary
(:mod:`.objects`: identity, CiA 402 objects, maxon objects 0x2006 / 0x30B0, a typical servo's
default PDO mapping), a :class:`~gatewaylab.canopen.node.Node` on ``bus``, an LSS slave, the CiA
402 power state machine and a motion plant stepped every control period (1 ms) on the injected
clock.

Controlword writes are applied at once (SDO or RPDO reception), the motion runs in the control
tick: this module is the control loop and the power state machine; the modes of operation that
compute each period's demand are :mod:`.modes`. Everything is documented in
``docs/canopen-drive.md``; choices the manuals leave open are listed in ``docs/decisions.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final, Protocol

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.canopen.cia402 import CONTROLWORD_NEXT, STATE_BITS, Command, Cw, OpMode, PdsState, Sw
from gatewaylab.canopen.emcy import ERR_GENERIC, ERR_PROFILE
from gatewaylab.canopen.errors import VALUE_RANGE_EXCEEDED, SdoAbort
from gatewaylab.canopen.lss import BIT_TIMING_TABLE, UNCONFIGURED, LssAddress, LssConfigStore, LssSlave
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import Clock, PeriodicTimer
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.homing import SUPPORTED_METHODS, HomingStatus
from gatewaylab.devices.canopen_drive.modes import POWER_OFF, Demand, OperationModes
from gatewaylab.devices.canopen_drive.objects import (
    DEVICE_NAME,
    DEVICE_TYPE,
    MAXON_VENDOR_ID,
    PRODUCT_CODE,
    REVISION,
    add_profile_objects,
    build_object_dictionary,
)
from gatewaylab.devices.canopen_drive.plant import AxisParams, ControlMode, Plant, Trapezoid
from gatewaylab.od import KeyObject, ObjectDictionary, WriteHook, key_object

#: The drive's own control period (s) when no host drives the cycle (IDX: 1 kHz position loop).
CONTROL_PERIOD = 0.001

#: EMCY / 0x603F error code of a position following error (CiA 402 / maxon 0x8611).
ERROR_FOLLOWING = 0x8611
#: Error register 0x1001 bit set with it (plus 'generic', which the EMCY producer adds): profile.
ERROR_REGISTER_FOLLOWING = ERR_PROFILE


#: Ranges of INTEGER32 / INTEGER16 as floats (the measured values are floats: a float compares
#: with a float faster than with an int); the saturated value rounds to the same int.
_I32 = (-2147483648.0, 2147483647.0)
_I16 = (-32768.0, 32767.0)
_I32_LOW: Final = -2147483648.0
_I32_HIGH: Final = 2147483647.0
_I16_LOW: Final = -32768.0
_I16_HIGH: Final = 32767.0

#: The actual values the control tick publishes every period, in this order (an event-driven
#: TPDO mapping them samples the dictionary as each one changes): (index, subindex) and the
#: range a measured value is saturated to before it is rounded; None for the digital inputs
#: and the statusword, which the drive computes as ints of their type.
_ACTUALS: tuple[tuple[tuple[int, int], tuple[float, float] | None], ...] = (
    ((0x6064, 0), _I32),   # position actual value
    ((0x606C, 0), _I32),   # velocity actual value
    ((0x6077, 0), _I16),   # torque actual value
    ((0x6074, 0), _I16),   # torque demand (the motor torque of the plant: no current loop)
    ((0x6062, 0), _I32),   # position demand value
    ((0x606B, 0), _I32),   # velocity demand value
    ((0x60F4, 0), _I32),   # following error actual value
    ((0x60FD, 0), None),   # digital inputs
    ((0x6041, 0), None),   # statusword
)
#: _ACTUALS' keys as the entries' own key objects (a dict finds an identical key without
#: comparing tuples; compiled code keeps them boxed): the puts of every control period
_ACTUAL_KEYS: Final[tuple[KeyObject, ...]] = tuple(key_object(*key) for key, _ in _ACTUALS)
_STATUSWORD_KEY: Final[tuple[KeyObject, ...]] = (key_object(0x6041, 0),)
# the objects the control tick reads every period
_K_CONTROLWORD: Final = key_object(0x6040, 0)
_K_QUICK_STOP_OPTION: Final = key_object(0x605A, 0)
_K_MAX_TORQUE: Final = key_object(0x6072, 0)
_K_FE_WINDOW: Final = key_object(0x6065, 0)
_K_FE_TIMEOUT: Final = key_object(0x6066, 0)


def _saturated_int(value: float, low: float, high: float) -> int:
    """``round(value)`` saturated to ``[low, high]`` (a measured value stored in an integer object).

    Rounds half to even as ``round`` does, with a floor and the exact fraction ``value - floor``
    (compiled these are C operations; ``round`` would be a call of the builtin). A NaN raises
    ValueError as ``round`` does."""
    if value < low:
        value = low
    elif value > high:
        value = high
    whole = math.floor(value)
    rest = value - whole
    if rest > 0.5 or (rest == 0.5 and whole & 1):
        return whole + 1
    return whole


class DriveEmcy(Protocol):
    """What the drive uses of its host's EMCY producer (:class:`~gatewaylab.canopen.emcy.Emcy`)."""

    @property
    def active(self) -> dict[int, int]:
        """Active errors: code -> error register bits."""

    def raise_error(self, code: int, register_bits: int = ERR_GENERIC, info: bytes = b"") -> None:
        """Send an error (once per error event)."""

    def clear_error(self, code: int) -> None:
        """The error went away: 'error reset'."""


class DriveHost(Protocol):
    """What the drive uses of the node that hosts it: a CANopen :class:`Node`, or another
    protocol's stand-in (the EtherCAT drive's ``CoeHost``). A Protocol, not a base class: a
    compiled ``Node`` is a native class, and a compiled attribute typed ``Node`` refuses anything else."""

    @property
    def nmt_state(self) -> NmtState:
        """Statusword bit 9 'remote' follows NMT Operational."""

    @property
    def running(self) -> bool:
        """Switched on (between start and stop)."""

    @property
    def emcy(self) -> DriveEmcy:
        """The EMCY producer of the drive's errors."""

    def set(self, index: int, subindex: int, value: Any) -> None:
        """The device's own write of a typed value (no access checks, no hooks)."""

    def on_write(self, index: int | range, callback: WriteHook) -> None:
        """``callback(index, subindex, value)`` after a remote write was stored."""

    def on_nmt_change(self, callback: Callable[[NmtState, NmtState], None]) -> None:
        """``callback(old, new)`` on every NMT state change."""

    def on_reset(self, callback: Callable[[bool], None]) -> None:
        """``callback(reset_node)`` at the start of an NMT reset."""

    def start(self) -> None:
        """Power on the communication side."""

    def stop(self) -> None:
        """Power off the communication side."""


class Drive(OperationModes):
    """A maxon IDX-like CiA 402 servo on a virtual CAN bus (see module docstring)."""

    #: the CANopen node of a drive on CAN (a hosted drive has none: see ``host``)
    node: Node
    #: what the drive uses of its node: ``node``, or the host given by another protocol
    host: DriveHost

    def __init__(self, clock: Clock, bus: VirtualBus | None, node_id: int | None, serial: int, name: str = "",
                 store_path: Path | None = None, params: AxisParams | None = None, *,
                 od: ObjectDictionary | None = None, host: DriveHost | None = None) -> None:
        """``od`` and ``host``: another protocol hosts the drive (the EtherCAT drive: its slave's
        dictionary holds the rows of :func:`add_profile_objects`, ``host`` offers what the drive
        uses of a Node, :class:`DriveHost`); then no CANopen node and no LSS slave are built,
        ``bus`` is not used and the drive has no ``node``."""
        if node_id is not None and not 1 <= node_id <= 127:
            raise ConfigError(f"drive node_id {node_id} outside 1..127")
        if not 0 <= serial <= 0xFFFFFFFF:
            raise ConfigError(f"drive serial {serial} is not a u32")
        self.clock = clock
        self.bus = bus
        self.name = name or f"drive{serial:x}"
        self.serial = serial
        self.store_path = store_path
        lss_store = LssConfigStore(store_path.with_name(store_path.name + ".lss.json")) if store_path else None
        stored = lss_store.load() if lss_store is not None else None
        if stored is not None:
            node_id = None if stored[0] == UNCONFIGURED else stored[0]
        self.od = od if od is not None else build_object_dictionary(serial, node_id, params=params)
        #: the dictionary's value table (typed values), read directly on the 1 kHz hot path
        #: with the entries' key objects (``key_object``)
        self._v: dict[Any, Any] = self.od.values
        self._lss: LssSlave | None = None
        if host is not None:
            self.host = host
        else:
            if bus is None:
                raise ConfigError(f"drive {self.name}: a CANopen drive needs a bus")
            self.node = self.host = Node(clock, bus, node_id, self.od, name=self.name, store_path=store_path)
            if stored is not None:
                rate = BIT_TIMING_TABLE[stored[1]] if stored[1] < len(BIT_TIMING_TABLE) else None
                if rate is not None:
                    self.node.controller.bitrate = rate
            self._lss = LssSlave(self.node, LssAddress(MAXON_VENDOR_ID, PRODUCT_CODE, REVISION, serial),
                                 store=lss_store)
        self.plant = Plant(params or AxisParams())
        self.period = CONTROL_PERIOD
        #: what the rig's ready file lists for this drive (set by the rig: its EDS, for monitors)
        self.ready_extra: dict[str, Any] = {}
        self.faults = 0
        self.active_errors: set[int] = set()
        self._timer: PeriodicTimer | None = None
        self._enter(PdsState.NOT_READY_TO_SWITCH_ON)
        self._init_motion()
        self.host.on_write(0x6040, self._on_controlword)
        self.host.on_write(0x6060, self._on_mode)
        self.host.on_write(0x6098, self._on_homing_method)
        self.host.on_nmt_change(self._on_nmt_change)
        self.host.on_reset(self._on_reset)

    # -- life cycle -------------------------------------------------------------------------
    def _init_motion(self) -> None:
        self.controlword = 0
        self._set_mode(OpMode(self._v[0x6061, 0]))
        self.offset = 0.0
        self.profile = Trapezoid()
        self.demand = 0.0
        self.demand_velocity = 0.0
        self.target = None
        self.pending_target = None
        self.setpoint_ack = False
        self.target_reached = False
        self.internal_limit = False
        self.fe_time = 0.0
        self.fe_warning = False
        self.in_window_time = 0.0
        self.homing = None
        self.homing_status = HomingStatus.IDLE
        self.halted = False
        self.prev_csp_target = None
        self.csp_changed_at = 0.0
        self.csp_span = CONTROL_PERIOD
        self.csp_velocity = 0.0

    def start(self) -> None:
        """Power on: boot the node, leave 'not ready to switch on', start the control tick."""
        self.host.start()
        self._transition(PdsState.SWITCH_ON_DISABLED, 1)   # after the self-test
        self._publish()
        if self._timer is None:
            self._timer = self.clock.call_every(self.period, self._tick)

    def ready_info(self) -> dict[str, Any]:
        """Rig participant protocol: a drive publishes no endpoints, only what the rig set in
        ``ready_extra`` (its EDS file, so a monitor decodes its PDOs)."""
        return dict(self.ready_extra)

    def stop(self) -> None:
        """Power off: stop the control tick, the LSS timers and the node."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._lss is not None:
            self._lss.stop()
        self.host.stop()

    @property
    def running(self) -> bool:
        """Switched on: its node (or the protocol that hosts it) runs (fault injection's power cycle)."""
        return self.host.running

    @property
    def lss(self) -> LssSlave:
        """The LSS slave of a CANopen drive (a drive hosted by another protocol has none)."""
        if self._lss is None:
            raise ConfigError(f"drive {self.name} has no LSS slave (not on CAN)")
        return self._lss

    def set_external_cycle(self, external: bool) -> None:
        """EtherCAT synchronisation (ETG.1020): ``True`` stops the drive's own control timer, the
        host then runs each control period with :meth:`control_period` (SYNC0 or SM event);
        ``False`` (free run) restarts the timer at the 1 ms control period."""
        if external and self._timer is not None:
            self._timer.cancel()
            self._timer = None
        elif not external and self._timer is None:
            self.period = CONTROL_PERIOD
            self._timer = self.clock.call_every(self.period, self._tick)

    def control_period(self, dt: float) -> None:
        """One control period of ``dt`` seconds run by the host (see :meth:`set_external_cycle`)."""
        self.period = dt
        self._tick()

    # -- object hooks -----------------------------------------------------------------------
    def _on_mode(self, *args: Any) -> None:
        mode = int(self._v[0x6060, 0])
        if mode == self._mode_code:
            return          # the same mode written again (a cyclic master's RxPDO)
        try:
            op = OpMode(mode)
        except ValueError:
            raise SdoAbort(VALUE_RANGE_EXCEEDED, f"mode {mode} not supported") from None
        if op is not self.mode:
            self._set_mode(op)
            self._restart_motion()
            self._publish()

    def _set_mode(self, op: OpMode) -> None:
        """The active mode and its display 0x6061 (the control tick runs its handler, _mode_demand)."""
        self.mode = op
        self._mode_code = int(op)
        self.host.set(0x6061, 0, int(op))

    def _mode_demand(self, dt: float) -> Demand:
        """The demand of one control period in 'operation enabled': the handler of the mode
        (called by name, not through a table of bound methods: compiled, a direct call)."""
        mode = self.mode
        if mode is _CSP:
            return self._cyclic_position(dt)
        if mode is _PP:
            return self._profile_position(dt)
        if mode is _CSV:
            return self._cyclic_velocity(dt)
        if mode is _CST:
            return self._cyclic_torque(dt)
        if mode is _PV:
            return self._profile_velocity(dt)
        if mode is _HOMING:
            return self._homing(dt)
        return self._hold(dt)

    @staticmethod
    def _on_homing_method(index: int, sub: int, value: Any) -> None:
        if int(value) not in SUPPORTED_METHODS:
            raise SdoAbort(VALUE_RANGE_EXCEEDED, f"homing method {value} not supported")

    def _on_nmt_change(self, old: NmtState, new: NmtState) -> None:
        if new is NmtState.PRE_OPERATIONAL and old is NmtState.INITIALISING:
            # after a reset the mode object is back at its (or its stored) value
            self._sync_mode()
        self._publish()   # statusword bit 9 'remote' follows NMT Operational (IDX table 3-11)

    def _on_reset(self, reset_node: bool) -> None:
        if reset_node:
            # IDX guide table 3-11: reset node = power cycle of the drive software; the axis stays
            # where it is, the power stage switches off and homing is lost.
            self.plant.state.velocity = 0.0
            self.plant.reset_integrator()
            self._clear_errors(send=False)
            self._init_motion()
            self._transition(PdsState.SWITCH_ON_DISABLED, 1)   # power on again (0 and 1)

    def _sync_mode(self) -> None:
        try:
            op = OpMode(int(self._v[0x6060, 0]))
        except ValueError:
            op = OpMode.NO_MODE
        self._set_mode(op)

    def _on_controlword(self, *args: Any) -> None:
        cw: int = self._v[_K_CONTROLWORD]
        prev, self.controlword = self.controlword, cw
        # next_state(state, decode_command(cw, prev)) from one precomputed table (every SYNC)
        hit = self._cw_next[(cw & 0x8F) | ((prev & 0x80) << 1)]
        # CiA 402: transition 16 only with the quick stop option codes 5..8
        if hit is not None and not (hit[1] == 16 and int(self._v[_K_QUICK_STOP_OPTION]) < 5):
            self._transition(hit[0], hit[1])
        self._setpoint_handshake(cw)
        if self.state is _OPERATION_ENABLED:
            self.halted = bool(cw & _CW_HALT)
            mode = self.mode
            if mode is _PP or mode is _HOMING:   # the modes with a new-set-point bit
                self._mode_control(cw, prev)
        self._publish()

    def _transition(self, new: PdsState, number: int) -> None:
        """Enter ``new`` by CiA 402 transition ``number`` and do what it does to the motion.

        Every state change of the drive goes through here: controlword commands (the table
        ``cia402.TRANSITIONS``) and the drive's own transitions: 1 (power on), 12 (quick stop
        ramp ended), 13 (fault), 14 (fault reaction ended). The caller publishes the statusword.
        """
        old = self.state
        self._enter(new)
        if new is not _OPERATION_ENABLED and new is not _QUICK_STOP_ACTIVE:
            # the trajectory generator drops its set-points (enabling again starts from the actual
            # position): none is acknowledged; quick stop active keeps them for transition 16
            self.setpoint_ack = False
        if new is _OPERATION_ENABLED:
            if old is not PdsState.QUICK_STOP_ACTIVE:   # 16 resumes the running motion
                self._restart_motion()
        elif number == 11:     # quick stop: ramp down from the demand
            self.profile.reset(self.demand, self.plant.state.velocity)
        elif number == 13:     # fault reaction: ramp down from where the axis is
            self.profile.reset(self.plant.state.position + self.offset, self.plant.state.velocity)
            self.fe_time = 0.0
        elif number == 15:     # fault reset
            self._clear_errors(send=True)

    def _enter(self, new: PdsState) -> None:
        """The state and what depends on it alone, looked up once here: its statusword bits and
        its row of the controlword table (an Enum-keyed lookup hashes in Python: every period)."""
        self.state = new
        self._state_bits = STATE_BITS[new]
        self._cw_next = CONTROLWORD_NEXT[new]

    def _restart_motion(self) -> None:
        """Take over the actual position as demand (enable, mode change)."""
        x = self.plant.state.position + self.offset
        self.demand = x
        self.profile.reset(x, 0.0)
        self.target = None
        self.pending_target = None
        self.target_reached = True
        self.setpoint_ack = False
        self.prev_csp_target = None
        self.fe_time = 0.0
        self.halted = False
        self.homing = None
        self.homing_status = HomingStatus.IDLE
        self.plant.reset_integrator()

    # -- control tick -----------------------------------------------------------------------
    def _tick(self) -> None:
        """One control period: the demand of the state (the mode's handler in operation
        enabled), one plant step, following error supervision, the actual values."""
        dt = self.period
        plant = self.plant
        st = plant.state
        state = self.state
        if state is _OPERATION_ENABLED:
            demand = self._mode_demand(dt)
        elif state is _QUICK_STOP_ACTIVE or state is _FAULT_REACTION_ACTIVE:
            demand = self._stop_ramp(dt)
        elif st.velocity == 0.0 and plant.external_torque == 0.0 and not self.fe_warning:
            return   # power stage off and the axis at rest: nothing can change
        else:
            demand = POWER_OFF
        control, position, velocity, acceleration, torque = demand
        offset = self.offset
        v = self._v
        max_torque: int = v[_K_MAX_TORQUE]
        plant.step(dt, control, position - offset, velocity, acceleration, torque, float(max_torque))
        x = st.position + offset
        supervised = control is _POSITION and state is _OPERATION_ENABLED
        self.demand = position if control is _POSITION else x
        self.demand_velocity = velocity
        fe = self.demand - x if supervised else 0.0
        # following error supervision: outside the window 0x6065 for longer than 0x6066 ms is a fault
        window: int = v[_K_FE_WINDOW]
        if not supervised or window == 0xFFFFFFFF or abs(fe) <= window:
            self.fe_time = 0.0
            self.fe_warning = False
        else:
            self.fe_warning = True
            self.fe_time += dt
            if self.fe_time * 1000.0 > int(v[_K_FE_TIMEOUT]) + 1e-9 and self.state is _OPERATION_ENABLED:
                self.fault(ERROR_FOLLOWING, ERROR_REGISTER_FOLLOWING)
        self._publish_actuals(x, fe)

    def _stop_ramp(self, dt: float) -> Demand:
        """Quick stop / fault reaction: ramp to standstill, then the CiA 402 follow-up state
        (transition 12 or 14); quick stop option 0 switches the power stage off at once."""
        option = int(self._v[0x605A, 0])
        fault = self.state is _FAULT_REACTION_ACTIVE
        if not fault and option == 0:
            self._transition(PdsState.SWITCH_ON_DISABLED, 12)
            return POWER_OFF
        dec_index = 0x6084 if (not fault and option in (1, 5)) else 0x6085
        # the demand ramp has ended (the axis may still be pushed by a load)
        if self.profile.to_velocity(0.0, 1.0, float(self._v[dec_index, 0]), dt):
            if fault:
                self._transition(PdsState.FAULT, 14)
            elif option < 5:
                self._transition(PdsState.SWITCH_ON_DISABLED, 12)
        return self._follow_profile()

    def fault(self, error_code: int, error_register: int, data: bytes = b"") -> None:
        """Enter 'fault reaction active' (transition 13): 0x603F, EMCY, then ramp down to FAULT."""
        if self.state in (PdsState.FAULT, PdsState.FAULT_REACTION_ACTIVE):
            return
        self.faults += 1
        self.host.set(0x603F, 0, error_code)
        self._raise_error(error_code, error_register, data)
        self._transition(PdsState.FAULT_REACTION_ACTIVE, 13)
        self._publish()

    def _raise_error(self, error_code: int, error_register: int, data: bytes) -> None:
        self.active_errors.add(error_code)
        self.host.emcy.raise_error(error_code, error_register, data)

    def _clear_errors(self, send: bool) -> None:
        """Fault reset (transition 15): 0x603F cleared, EMCY 'error reset' for each drive error."""
        self.host.set(0x603F, 0, 0)
        for code in sorted(self.active_errors):
            if send:
                self.host.emcy.clear_error(code)
            else:
                self.host.emcy.active.pop(code, None)
        self.active_errors.clear()

    # -- outputs ----------------------------------------------------------------------------
    def statusword(self) -> int:
        """0x6041 from the FSA state, NMT state and the mode's bits (plain ints: 1 kHz path)."""
        # enum members through module constants: Enum class attribute access is slow in 3.11
        state = self.state
        sw = self._state_bits
        if self.host.nmt_state is _NMT_OPERATIONAL:
            sw |= _SW_REMOTE
        if self.fe_warning:
            sw |= _SW_WARNING
        if self.internal_limit or self.plant.state.saturated:
            sw |= _SW_INTERNAL_LIMIT
        mode = self.mode
        enabled = state is _OPERATION_ENABLED
        if mode is _CSP:
            if enabled:
                sw |= _SW_BIT12
            if self.fe_warning:
                sw |= _SW_BIT13
        elif mode is _PP:
            if self.target_reached or (self.halted and self.profile.velocity == 0.0):
                sw |= _SW_TARGET_REACHED
            if self.setpoint_ack:
                sw |= _SW_BIT12
            if self.fe_warning:
                sw |= _SW_BIT13
        elif mode is _PV:
            if self.target_reached:
                sw |= _SW_TARGET_REACHED
            if abs(self.plant.state.velocity) < 1.0:
                sw |= _SW_BIT12
        elif mode is _HOMING:
            sw |= self.homing_status.bits
        elif enabled and (mode is _CSV or mode is _CST):
            sw |= _SW_BIT12
        return sw

    def _publish(self) -> None:
        """The statusword into the dictionary (event-driven TPDOs mapping it see a change)."""
        self.od.put_many(_STATUSWORD_KEY, [self.statusword()], typed=True)

    def _publish_actuals(self, x: float, fe: float) -> None:
        """The actual values of this period into the dictionary, in the order of ``_ACTUALS``:
        the measured ones rounded and saturated to their type, so they are stored typed."""
        plant = self.plant
        st = plant.state
        torque = _saturated_int(st.torque, _I16_LOW, _I16_HIGH)
        self.od.put_many(_ACTUAL_KEYS, [
            _saturated_int(x, _I32_LOW, _I32_HIGH),
            _saturated_int(st.velocity, _I32_LOW, _I32_HIGH),
            torque,
            torque,
            _saturated_int(self.demand, _I32_LOW, _I32_HIGH),
            _saturated_int(self.demand_velocity, _I32_LOW, _I32_HIGH),
            _saturated_int(fe, _I32_LOW, _I32_HIGH),
            plant.digital_inputs(),
            self.statusword(),
        ], typed=True)


_CW_HALT: Final = int(Cw.HALT)
_SW_REMOTE: Final = int(Sw.REMOTE)
_SW_WARNING: Final = int(Sw.WARNING)
_SW_INTERNAL_LIMIT: Final = int(Sw.INTERNAL_LIMIT)
_SW_TARGET_REACHED: Final = int(Sw.TARGET_REACHED)
_SW_BIT12: Final = int(Sw.OP_SPECIFIC_12)
_SW_BIT13: Final = int(Sw.OP_SPECIFIC_13)
# enum members through module constants: Enum class attribute access is slow in 3.11 (Final:
# compiled, a C static instead of a lookup in the module's dict)
_CSP: Final = OpMode.CYCLIC_SYNC_POSITION
_PP: Final = OpMode.PROFILE_POSITION
_PV: Final = OpMode.PROFILE_VELOCITY
_HOMING: Final = OpMode.HOMING
_CSV: Final = OpMode.CYCLIC_SYNC_VELOCITY
_CST: Final = OpMode.CYCLIC_SYNC_TORQUE
_NMT_OPERATIONAL: Final = NmtState.OPERATIONAL
_OPERATION_ENABLED: Final = PdsState.OPERATION_ENABLED
_QUICK_STOP_ACTIVE: Final = PdsState.QUICK_STOP_ACTIVE
_FAULT_REACTION_ACTIVE: Final = PdsState.FAULT_REACTION_ACTIVE
_POSITION: Final = ControlMode.POSITION


#: the dictionary's names stay importable from here (objects.py holds them since issue 22)
__all__ = ["DEVICE_NAME", "DEVICE_TYPE", "MAXON_VENDOR_ID", "PRODUCT_CODE", "REVISION", "Command", "Demand", "Drive",
           "add_profile_objects", "build_object_dictionary"]
