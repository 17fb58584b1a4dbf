"""The CiA 402 modes of operation of the drive: one control period of each mode, and its set-point bits.

:class:`OperationModes` holds what the modes share with the drive's control loop (the motion state:
demand, profile, target, homing run, the CSP set-point stream) and computes the :data:`Demand` of
one control period in 'operation enabled' for PP, PV, HM, CSP, CSV, CST (CiA 402 / IDX firmware
guide chapter 3.4), plus the new-set-point handling of PP and HM. :class:`~.device.Drive` is the
control loop and power state machine around it.
"""

from __future__ import annotations

from typing import Any, Final

from gatewaylab.canopen.cia402 import Cw, OpMode, PdsState
from gatewaylab.common.clock import Clock
from gatewaylab.devices.canopen_drive.homing import HomingRun, HomingStatus
from gatewaylab.devices.canopen_drive.plant import ControlMode, Plant, Trapezoid
from gatewaylab.od import key_object


def _clamp(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


#: What the plant follows in one control period, as a mode handler returns it:
#: ``(control, position, velocity, acceleration, torque)``. ``position`` is the position demand
#: value 0x6062 in user units (the plant gets it minus the homing offset) and counts only for
#: ``ControlMode.POSITION``, otherwise the demand follows the actual position; ``velocity`` is
#: the velocity demand 0x606B (the feed-forward of a position demand), ``acceleration`` its
#: feed-forward, ``torque`` the command of ``ControlMode.TORQUE`` (per mille). A plain tuple,
#: not a NamedTuple: building one of those every period costs 2-3 % of the drive benchmark.
Demand = tuple[ControlMode, float, float, float, float]


#: The power stage is off: the axis coasts and friction stops it.
POWER_OFF: Demand = (ControlMode.OFF, 0.0, 0.0, 0.0, 0.0)


class OperationModes:
    """The modes of operation of a CiA 402 drive (see the module docstring); the drive initialises
    the motion state below (``Drive._init_motion``) and calls one handler per control period."""

    # what the handlers read: the drive's clock, plant, dictionary values, state and mode
    clock: Clock
    plant: Plant
    state: PdsState
    mode: OpMode
    #: ``int(mode)``: 0x6060 is written every cycle over EtherCAT, mostly unchanged (compared as an int,
    #: no enum built)
    _mode_code: int
    #: the dictionary's value table (typed values), read directly on the 1 kHz hot path (the
    #: objects of every period through their key objects, ``key_object``: see od.types)
    _v: dict[Any, Any]
    # the motion state the handlers keep
    #: user position = physical plant position + offset (homing moves the offset)
    offset: float
    profile: Trapezoid
    demand: float
    target: float | None
    pending_target: float | None
    setpoint_ack: bool
    target_reached: bool
    internal_limit: bool
    in_window_time: float
    homing: HomingRun | None
    homing_status: HomingStatus
    halted: bool
    prev_csp_target: float | None
    csp_changed_at: float
    csp_span: float
    csp_velocity: float

    def _mode_control(self, cw: int, prev: int) -> None:
        """The new-set-point bit (4) of PP and HM in Operation enabled (halt, bit 8, is set by
        _on_controlword for every mode; the drive clears the set-point acknowledge of a cleared
        bit 4 in every state, :meth:`_setpoint_handshake`)."""
        rising = cw & ~prev
        mode = self.mode
        if mode is _PP:
            if rising & _CW_NEW_SETPOINT:
                self._new_setpoint(cw)
        elif mode is _HOMING:
            if rising & _CW_NEW_SETPOINT:
                self._start_homing()
            run = self.homing
            if self.halted and run is not None and self.homing_status in _HOMING_RUNNING:
                run.halt()
                self.homing_status = HomingStatus.INTERRUPTED
                # ramp down from where the homing profile is, in user coordinates
                self.profile.reset(run.profile.position + self.offset, run.profile.velocity)

    def _setpoint_handshake(self, cw: int) -> None:
        """PP set-point acknowledge (statusword bit 12) follows the new-set-point bit (controlword
        bit 4) down in every state: CiA 402-2 profile position mode, set-point transmission -- once
        the host releases bit 4 the drive signals with bit 12 = 0 that it accepts new data."""
        if not cw & _CW_NEW_SETPOINT:
            self.setpoint_ack = False

    def _soft_limits(self, x: float) -> float:
        v = self._v     # typed values: integer objects hold ints
        low: int = v[_K_MIN_POSITION]
        high: int = v[_K_MAX_POSITION]
        if low < high:
            clamped = low if x < low else high if x > high else x
            if clamped != x:
                self.internal_limit = True
            return clamped
        return x

    def _new_setpoint(self, cw: int) -> None:
        target = float(int(self._v[0x607A, 0]))
        if cw & Cw.RELATIVE:
            base = self.target if self.target is not None else self.demand
            target += base
        self.internal_limit = False
        target = self._soft_limits(target)
        moving = self.target is not None and not self.target_reached
        if moving and not cw & Cw.CHANGE_IMMEDIATELY:
            if self.pending_target is not None:
                return   # buffer full: no acknowledge (CiA 402 single set-point)
            self.pending_target = target
        else:
            self.target = target
            self.pending_target = None
            self.target_reached = False
            self.in_window_time = 0.0
        self.setpoint_ack = True

    def _start_homing(self) -> None:
        method = int(self._v[0x6098, 0])
        run = HomingRun(method, float(self._v[0x6099, 1]), float(self._v[0x6099, 2]),
                        float(self._v[0x609A, 0]))
        run.start(self.plant.state.position)
        self.homing = run
        self.homing_status = run.status
        if run.home_physical is not None and run.status is HomingStatus.REACHED:
            self._set_home(run.home_physical)   # methods 35/37: done at once

    def _set_home(self, physical: float) -> None:
        self.offset = float(int(self._v[0x30B0, 0])) - physical
        self.demand = self.plant.state.position + self.offset
        self.profile.reset(self.demand, 0.0)


    # -- the mode handlers: one control period of a mode of operation in 'operation enabled' --
    def _max_velocity(self) -> float:
        return float(min(int(self._v[0x607F, 0]), int(self._v[0x6080, 0])))

    def _follow_profile(self) -> Demand:
        prof = self.profile
        return (_POSITION, prof.position, prof.velocity, prof.acceleration, 0.0)

    def _hold(self, dt: float) -> Demand:
        """No mode: hold the position."""
        return (_POSITION, self.demand, 0.0, 0.0, 0.0)

    def _profile_position(self, dt: float) -> Demand:
        """PP: a trapezoid to the target (0x6081, 0x6083, 0x6084); halt ramps down with 0x6084."""
        v = self._v
        prof = self.profile
        if self.halted:
            prof.to_velocity(0.0, 1.0, float(v[0x6084, 0]), dt)
        elif self.target is not None and not self.target_reached:
            vel = min(float(v[0x6081, 0]), self._max_velocity())
            if prof.to_position(self.target, vel, float(v[0x6083, 0]), float(v[0x6084, 0]), dt):
                self._check_window(dt)
        return self._follow_profile()

    def _profile_velocity(self, dt: float) -> Demand:
        """PV: ramp to 0x60FF with 0x6083 / 0x6084 (0 while halted); target reached from the
        velocity window 0x606D / 0x606E."""
        v = self._v
        vmax = self._max_velocity()
        commanded = float(int(v[0x60FF, 0]))
        target = 0.0 if self.halted else _clamp(commanded, -vmax, vmax)
        self.internal_limit = target != commanded and not self.halted
        if abs(self.plant.state.velocity - target) <= int(v[0x606D, 0]):
            self.in_window_time += dt
        else:
            self.in_window_time = 0.0
        self.target_reached = self.in_window_time * 1000.0 >= int(v[0x606E, 0]) - 1e-9
        prof = self.profile
        prof.to_velocity(target, float(v[0x6083, 0]), float(v[0x6084, 0]), dt)
        return (_VELOCITY, 0.0, prof.velocity, prof.acceleration, 0.0)

    def _homing(self, dt: float) -> Demand:
        """HM: the homing run's profile (physical coordinates) until it ends, then hold; halt
        and an interrupted run ramp down with 0x609A."""
        run = self.homing
        if run is None or self.homing_status not in _HOMING_RUNNING:
            if self.halted or (run is not None and run.status is HomingStatus.INTERRUPTED):
                self.profile.to_velocity(0.0, 1.0, float(self._v[0x609A, 0]), dt)
            return self._follow_profile()
        found_before = run.home_physical
        run.step(dt, self.plant.digital_inputs(), self.plant.state.position)
        if found_before is None and run.home_physical is not None:
            # shift the user frame; the profile keeps running in physical coordinates
            self.offset = float(int(self._v[0x30B0, 0])) - run.home_physical
        self.homing_status = run.status
        prof = run.profile
        demand = prof.position + self.offset
        if run.status not in _HOMING_RUNNING:
            self.profile.reset(demand, 0.0)   # hold the home position afterwards
        return (_POSITION, demand, prof.velocity, prof.acceleration, 0.0)

    def _cyclic_position(self, dt: float) -> Demand:
        """CSP: 0x607A + 0x60B0 within the software limits, feed-forward from the set-point
        stream + 0x60B1."""
        v = self._v
        self.internal_limit = False
        target_position: int = v[_K_TARGET_POSITION]
        position_offset: int = v[_K_POSITION_OFFSET]
        target = self._soft_limits(float(target_position + position_offset))
        # velocity feed-forward from the set-point stream: change / time between changes, held
        # until the next set-point is late (so master cycles other than 1 ms still run smoothly)
        now = self.clock.now()
        prev = self.prev_csp_target
        self.prev_csp_target = target
        if prev is None:
            self.csp_changed_at, self.csp_span, self.csp_velocity = now, dt, 0.0
        elif target != prev:
            span = now - self.csp_changed_at
            if span < dt:     # a set-point within one period of the previous change
                span = dt
            self.csp_velocity = (target - prev) / span
            self.csp_changed_at, self.csp_span = now, span
        elif now - self.csp_changed_at > self.csp_span + 0.5 * dt:
            self.csp_velocity = 0.0
        velocity_offset: int = v[_K_VELOCITY_OFFSET]
        return (_POSITION, target, self.csp_velocity + float(velocity_offset), 0.0, 0.0)

    def _cyclic_velocity(self, dt: float) -> Demand:
        """CSV: 0x60FF + 0x60B1, limited to min(0x607F, 0x6080)."""
        raw = float(int(self._v[0x60FF, 0]) + int(self._v[0x60B1, 0]))
        vmax = self._max_velocity()
        target = _clamp(raw, -vmax, vmax)
        self.internal_limit = target != raw
        return (_VELOCITY, 0.0, target, 0.0, 0.0)

    def _cyclic_torque(self, dt: float) -> Demand:
        """CST: 0x6071 + 0x60B2, limited to 0x6072."""
        raw = float(int(self._v[0x6071, 0]) + int(self._v[0x60B2, 0]))
        max_torque = float(self._v[0x6072, 0])
        torque = _clamp(raw, -max_torque, max_torque)
        self.internal_limit = torque != raw
        return (_TORQUE, 0.0, 0.0, 0.0, torque)

    def _check_window(self, dt: float) -> None:
        """PP target reached: actual position within 0x6067 for 0x6068 ms after the profile ended."""
        assert self.target is not None
        x = self.plant.state.position + self.offset
        if abs(self.target - x) <= int(self._v[0x6067, 0]):
            self.in_window_time += dt
        else:
            self.in_window_time = 0.0
        if self.in_window_time * 1000.0 >= int(self._v[0x6068, 0]) - 1e-9:
            self.target_reached = True
            if self.pending_target is not None:
                self.target, self.pending_target = self.pending_target, None
                self.target_reached = False
                self.in_window_time = 0.0


_CW_NEW_SETPOINT: Final = int(Cw.NEW_SETPOINT)
# enum members through module constants: Enum class attribute access is slow in 3.11 (Final:
# compiled, a C static instead of a lookup in the module's dict)
_PP: Final = OpMode.PROFILE_POSITION
_HOMING: Final = OpMode.HOMING
_POSITION: Final = ControlMode.POSITION
_VELOCITY: Final = ControlMode.VELOCITY
_TORQUE: Final = ControlMode.TORQUE
_HOMING_RUNNING: Final = (HomingStatus.IN_PROGRESS, HomingStatus.ATTAINED)
# the objects CSP reads every period, by their key objects
_K_TARGET_POSITION: Final = key_object(0x607A, 0)
_K_POSITION_OFFSET: Final = key_object(0x60B0, 0)
_K_VELOCITY_OFFSET: Final = key_object(0x60B1, 0)
_K_MIN_POSITION: Final = key_object(0x607D, 1)
_K_MAX_POSITION: Final = key_object(0x607D, 2)
