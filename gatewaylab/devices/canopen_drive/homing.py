"""CiA 402 homing mode (6) procedures, stepped once per control period.

Supported methods (0x6098), CiA 402 V4.0 homing methods:

* 35 and 37 -- current position: the position where homing starts becomes the home position.
* 17 -- negative limit switch: move negative at the switch-search speed (0x6099:01) until the
  negative limit switch is active, then positive at the zero-search speed (0x6099:02) until it
  becomes inactive again; that edge is the home position.
* 18 -- positive limit switch: the mirror image of 17.

A run works in the plant's physical position (inc) and ends with the physical position of the
home edge; the drive then shifts its user positions so that the edge reads as the maxon home
position 0x30B0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from gatewaylab.devices.canopen_drive.plant import Trapezoid

__all__ = ["NEGATIVE_LIMIT", "POSITIVE_LIMIT", "SUPPORTED_METHODS", "HomingRun", "HomingStatus"]


NEGATIVE_LIMIT = 1 << 0   # 0x60FD bits
POSITIVE_LIMIT = 1 << 1

SUPPORTED_METHODS = frozenset({17, 18, 35, 37})


class HomingStatus(Enum):
    """Statusword bits 10/12/13 in homing mode (CiA 402 homing statusword table)."""

    IN_PROGRESS = "in progress"        # 10=0 12=0 13=0
    INTERRUPTED = "interrupted"        # 10=1 12=0 13=0 (halt)
    ATTAINED = "attained"              # 10=0 12=1 13=0 (still moving to the end)
    REACHED = "target reached"         # 10=1 12=1 13=0
    ERROR = "error"                    # 13=1
    IDLE = "idle"                      # not started: 10=0 12=0 13=0

    @property
    def bits(self) -> int:
        """Statusword bits 10, 12 and 13 of this homing status (CiA 402 homing mode)."""
        return _HOMING_BITS[self]


_HOMING_BITS: dict[HomingStatus, int] = {
    HomingStatus.IN_PROGRESS: 0x0000, HomingStatus.INTERRUPTED: 0x0400,
    HomingStatus.ATTAINED: 0x1000, HomingStatus.REACHED: 0x1400,
    HomingStatus.ERROR: 0x2000, HomingStatus.IDLE: 0x0000,
}


class _Phase(Enum):
    SEARCH = "search switch"
    LEAVE = "leave switch"
    STOP = "stop at home"
    DONE = "done"


@dataclass(slots=True)
class HomingRun:
    """One homing operation; ``step`` returns True when finished (see ``status``)."""

    method: int
    speed_switch: float      # inc/s, 0x6099:01
    speed_zero: float        # inc/s, 0x6099:02
    acceleration: float      # inc/s^2, 0x609A
    profile: Trapezoid = field(default_factory=Trapezoid)
    phase: _Phase = _Phase.SEARCH
    status: HomingStatus = HomingStatus.IN_PROGRESS
    #: Physical position that becomes the home position (set when found).
    home_physical: float | None = None

    def start(self, physical_position: float) -> None:
        """Begin the run from the axis's physical position; methods 35/37 are done at once."""
        self.profile.reset(physical_position, 0.0)
        if self.method in (35, 37):
            self.home_physical = physical_position
            self.phase = _Phase.DONE
            self.status = HomingStatus.REACHED
        elif self.method not in SUPPORTED_METHODS:
            self.phase = _Phase.DONE
            self.status = HomingStatus.ERROR
        else:
            self.phase = _Phase.SEARCH
            self.status = HomingStatus.IN_PROGRESS

    def step(self, dt: float, inputs: int, physical_position: float) -> bool:
        """Advance the setpoint one period using the switch inputs (0x60FD)."""
        if self.phase is _Phase.DONE:
            return True
        negative = self.method == 17
        switch = NEGATIVE_LIMIT if negative else POSITIVE_LIMIT
        sign = -1.0 if negative else 1.0
        prof = self.profile
        acc = self.acceleration
        if self.phase is _Phase.SEARCH:
            if inputs & switch:
                self.phase = _Phase.LEAVE
            else:
                prof.to_velocity(sign * self.speed_switch, acc, acc, dt)
                return False
        if self.phase is _Phase.LEAVE:
            if inputs & switch:
                prof.to_velocity(-sign * self.speed_zero, acc, acc, dt)
                return False
            self.home_physical = physical_position
            self.phase = _Phase.STOP
            self.status = HomingStatus.ATTAINED
        prof.to_velocity(0.0, acc, acc, dt)
        if prof.velocity == 0.0:
            self.phase = _Phase.DONE
            self.status = HomingStatus.REACHED
            return True
        return False

    def halt(self) -> None:
        """Controlword halt: stop the homing (statusword reads 'interrupted')."""
        if self.phase is not _Phase.DONE:
            self.phase = _Phase.DONE
            self.status = HomingStatus.INTERRUPTED
