"""A deterministic motion plant: one rotary axis with inertia, friction, limits and a cascaded
position / velocity controller, stepped with a fixed period.

Units are the drive's user units: position in increments (inc), velocity in inc/s, acceleration
in inc/s^2, torque in per mille of the rated torque (CiA 402 0x6076). The model, documented in
``docs/canopen-drive.md``:

    J * dw/dt = T_motor + T_ext - b * w - T_c * sign(w)       (w in rad/s, torques in Nm)
    T_motor   = clamp(T_cmd, +-T_max)
    T_cmd     = J * (K_v * (v_cmd - v) + K_i * integral(v_cmd - v)) + J * a_ff   (velocity loop)
    v_cmd     = v_ff + K_p * (x_cmd - x)                                          (position loop)

integrated with semi-implicit Euler at the control period (1 ms by default); Coulomb friction
holds the axis (stiction) when the drive torque does not exceed it. Hard mechanical stops clamp
the position and zero the velocity. The same inputs always give the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Final

__all__ = ["AxisParams", "AxisState", "ControlMode", "Plant", "Trapezoid"]


@dataclass(frozen=True, slots=True)
class AxisParams:
    """Physical and controller parameters of the emulated axis (defaults: a small maxon-like servo)."""

    inertia: float = 2.0e-5            # kg m^2, rotor + load
    rated_torque: float = 0.1          # Nm = 1000 per mille (0x6076)
    viscous_friction: float = 2.0e-6   # Nm / (rad/s)
    coulomb_friction: float = 2.0e-3  # Nm
    increments_per_rev: int = 4096     # encoder resolution (0x608F)
    kp: float = 60.0                   # 1/s, position loop gain
    kv: float = 400.0                  # 1/s, velocity loop gain
    ki: float = 8000.0                 # 1/s^2, velocity loop integral gain
    hard_stop_low: float | None = -200_000.0   # inc, mechanical end stops (None: none)
    hard_stop_high: float | None = 200_000.0
    negative_limit_switch: float = -150_000.0  # inc: switch active at or below this position
    positive_limit_switch: float = 150_000.0   # inc: switch active at or above this position
    home_switch: float = 0.0                   # inc: home switch active at or above

    @property
    def inc_per_rad(self) -> float:
        """Encoder increments per radian: converts the motor model's SI units to increments."""
        return self.increments_per_rev / (2.0 * math.pi)

    @property
    def accel_per_permille(self) -> float:
        """Acceleration in inc/s^2 that 1 per mille of rated torque gives on the bare inertia."""
        return self.rated_torque / 1000.0 / self.inertia * self.inc_per_rad


class ControlMode(Enum):
    """What the plant's controller follows in a step."""

    OFF = "off"            # power stage off: the axis coasts, friction stops it
    POSITION = "position"  # x_cmd (+ v_ff, a_ff)
    VELOCITY = "velocity"  # v_cmd (+ a_ff)
    TORQUE = "torque"      # torque command in per mille


_OFF: Final = ControlMode.OFF
_POSITION: Final = ControlMode.POSITION
_VELOCITY: Final = ControlMode.VELOCITY
_TORQUE: Final = ControlMode.TORQUE


class _StepConstants:
    """What ``Plant.step`` derives from its :class:`AxisParams`, computed once per params object.

    Typed fields, not a tuple: compiled, the arithmetic of ``step`` stays on C doubles (the values
    of an ``Any`` tuple made every operation a generic Python one)."""

    __slots__ = ("coulomb", "has_high", "has_low", "high", "inc_per_rad", "k", "ki", "kp", "kv", "low",
                 "params", "rated_torque", "viscous_friction")

    def __init__(self, p: AxisParams) -> None:
        self.params = p
        self.k: float = p.accel_per_permille
        self.kp: float = p.kp
        self.kv: float = p.kv
        self.ki: float = p.ki
        self.inc_per_rad: float = p.inc_per_rad
        self.viscous_friction: float = p.viscous_friction
        self.rated_torque: float = p.rated_torque
        self.coulomb: float = p.coulomb_friction / p.rated_torque * 1000.0
        high, low = p.hard_stop_high, p.hard_stop_low
        self.has_high = high is not None
        self.high: float = high if high is not None else 0.0
        self.has_low = low is not None
        self.low: float = low if low is not None else 0.0


@dataclass(slots=True)
class AxisState:
    """Where the simulated axis is after the last step, in encoder increments."""
    position: float = 0.0      # inc
    velocity: float = 0.0      # inc/s
    torque: float = 0.0        # per mille, produced by the motor in the last step
    integral: float = 0.0      # velocity-loop integrator (inc/s * s)
    saturated: bool = False    # the torque command hit the limit in the last step
    at_stop: bool = False      # the axis sits on a mechanical end stop


@dataclass(slots=True)
class Plant:
    """The axis and its controller; ``step`` advances it by ``dt`` seconds."""

    params: AxisParams = field(default_factory=AxisParams)
    state: AxisState = field(default_factory=AxisState)
    #: External load torque in per mille (fault injection / teaching: a blocked or loaded axis).
    external_torque: float = 0.0
    _consts: _StepConstants | None = field(default=None, init=False, repr=False, compare=False)

    def reset_integrator(self) -> None:
        """Forget the velocity loop's integral (enable, mode change, reset): no kick from old errors."""
        self.state.integral = 0.0

    def set_position(self, position: float) -> None:
        """Redefine the current position (homing); the physics does not move."""
        self.state.position = position

    def step(self, dt: float, mode: ControlMode, position: float = 0.0, velocity: float = 0.0,
             acceleration: float = 0.0, torque: float = 0.0, max_torque: float = 1000.0) -> None:
        """One control period: compute the motor torque for ``mode``, integrate the axis.

        The inputs may be passed by position (the drive's 1 kHz path does) or by keyword."""
        c = self._consts
        if c is None or c.params is not self.params:
            c = self._consts = _StepConstants(self.params)
        k = c.k
        coulomb = c.coulomb
        st = self.state
        v = st.velocity
        # k: inc/s^2 per per mille
        if mode is _OFF:
            cmd = 0.0
            st.integral = 0.0
        elif mode is _TORQUE:
            cmd = torque
            st.integral = 0.0
        else:
            v_cmd = velocity
            if mode is _POSITION:
                # compare with where the axis will be at the end of this step, so that the
                # actual position matches the set-point of the same instant (no one-step lead)
                v_cmd += c.kp * (position - st.position - v * dt)
            err = v_cmd - v
            cmd = (c.kv * err + c.ki * (st.integral + err * dt) + acceleration) / k
        limit = abs(max_torque)
        saturated = cmd > limit or cmd < -limit
        if saturated:
            cmd = limit if cmd > 0 else -limit
        elif mode is _POSITION or mode is _VELOCITY:
            # anti-windup: integrate only while the output is not saturated
            st.integral += (v_cmd - v) * dt
        st.saturated = saturated
        st.torque = cmd
        # forces in per mille of rated torque
        viscous = c.viscous_friction * (v / c.inc_per_rad) / c.rated_torque * 1000.0
        drive = cmd + self.external_torque - viscous
        if v == 0.0 and abs(drive) <= coulomb:
            acc = 0.0          # stiction holds the axis
        else:
            direction = v if v != 0.0 else drive
            acc = (drive - math.copysign(coulomb, direction)) * k
        v_new = v + acc * dt
        if v != 0.0 and (v_new > 0.0) != (v > 0.0) and abs(drive) <= coulomb:
            v_new = 0.0        # friction brings it to rest within the step, it does not reverse
        x_new = st.position + v_new * dt
        at_stop = False
        if c.has_high and x_new >= c.high:
            x_new, v_new, at_stop = c.high, min(v_new, 0.0), True
        if c.has_low and x_new <= c.low:
            x_new, v_new, at_stop = c.low, max(v_new, 0.0), True
        st.at_stop = at_stop
        st.velocity = v_new
        st.position = x_new

    # -- sensors --------------------------------------------------------------------------
    def digital_inputs(self, offset: float = 0.0) -> int:
        """CiA 402 0x60FD bits: 0 negative limit switch, 1 positive limit switch, 2 home switch.

        ``offset`` is the physical position of user position 0 (homing shifts user positions
        but the switches stay where the machine has them).
        """
        x = self.state.position + offset
        p = self.params
        return ((x <= p.negative_limit_switch)
                | (x >= p.positive_limit_switch) << 1
                | (x >= p.home_switch) << 2)


@dataclass(slots=True)
class Trapezoid:
    """Online trapezoidal profile generator (PP, PV, homing), one step per control period."""

    position: float = 0.0
    velocity: float = 0.0
    acceleration: float = 0.0

    def reset(self, position: float, velocity: float) -> None:
        """Start the profile anew at ``position`` moving at ``velocity``, not accelerating."""
        self.position, self.velocity, self.acceleration = position, velocity, 0.0

    def to_velocity(self, target: float, acc: float, dec: float, dt: float) -> bool:
        """Ramp the velocity towards ``target``; True once it is reached."""
        v = self.velocity
        if v == target:
            self.acceleration = 0.0
        else:
            speeding_up = (abs(target) > abs(v) and (target >= 0) == (v >= 0)) or v == 0.0
            rate = (acc if speeding_up else dec) * dt
            nv = min(v + rate, target) if target > v else max(v - rate, target)
            self.acceleration = (nv - v) / dt
            v = nv
        self.velocity = v
        self.position += v * dt
        return v == target

    def to_position(self, target: float, vmax: float, acc: float, dec: float, dt: float) -> bool:
        """Move towards ``target`` limited by vmax/acc/dec; True once there and at rest."""
        d = target - self.position
        v = self.velocity
        if d == 0.0 and v == 0.0:
            self.acceleration = 0.0
            return True
        s = 1.0 if d > 0 else -1.0
        # the largest speed from which the remaining distance still allows a stop
        v_allow = math.sqrt(2.0 * dec * abs(d))
        v_goal = s * min(vmax, v_allow)
        if (v_goal >= 0) == (v >= 0) and abs(v_goal) > abs(v):
            nv = min(v + acc * dt, v_goal) if v_goal > v else max(v - acc * dt, v_goal)
        else:
            nv = min(v + dec * dt, v_goal) if v_goal > v else max(v - dec * dt, v_goal)
        new_pos = self.position + nv * dt
        if (target - new_pos) * s <= 0.0 or (abs(target - new_pos) < 0.5 and abs(nv) <= dec * dt):
            self.acceleration = -v / dt
            self.position, self.velocity = target, 0.0
            return True
        self.acceleration = (nv - v) / dt
        self.position, self.velocity = new_pos, nv
        return False
