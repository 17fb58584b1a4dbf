"""CiA 402 behaviour of the drive through its object dictionary (node.write = what an SDO
download does), on the simulated clock only. IDX guide 3.1 (CiA 402 V4.0), table 3-11."""

from __future__ import annotations

import itertools
import struct

import pytest

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.cia402 import (
    TRANSITIONS,
    Command,
    PdsState,
    decode_command,
    next_state,
    state_from_statusword,
)
from gatewaylab.canopen.nmt import NmtCommand
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.od import SdoAbort


class Axis:
    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.bus = VirtualBus(self.clock, "can0")
        self.frames: list[CanFrame] = []
        self.bus.add_monitor(lambda f, t: self.frames.append(f))
        self.master = self.bus.attach("master")      # acknowledges the drive's frames
        self.drive = Drive(self.clock, self.bus, 3, 0x1003)
        self.drive.start()
        self.clock.advance(0.01)

    def w(self, index: int, sub: int, fmt: str, value: int) -> None:
        self.drive.node.write(index, sub, struct.pack("<" + fmt, value))

    def r(self, index: int, sub: int = 0) -> int:
        return int(self.drive.node.get(index, sub))

    def cw(self, value: int) -> None:
        self.w(0x6040, 0, "H", value)

    def sw(self) -> int:
        return self.r(0x6041)

    def enable(self, mode: int) -> None:
        self.w(0x6060, 0, "b", mode)
        for value in (0x06, 0x07, 0x0F):
            self.cw(value)
        assert state_from_statusword(self.sw()) is PdsState.OPERATION_ENABLED

    def until(self, cond, limit: float) -> float:  # type: ignore[no-untyped-def]
        end = self.clock.now() + limit
        while not cond():
            assert self.clock.now() < end, "condition not met in time"
            self.clock.advance(0.001)
        return self.clock.now()


@pytest.fixture
def axis() -> Axis:
    return Axis()


def test_statusword_patterns_per_state(axis: Axis) -> None:
    """CiA 402 statusword bits 0-6 for each state reached by controlword commands."""
    expected = [(None, 0x0040), (0x06, 0x0031), (0x07, 0x0033), (0x0F, 0x0037), (0x07, 0x0033),
                (0x0F, 0x0037), (0x02, 0x0017), (0x00, 0x0040)]
    for value, bits in expected:
        if value is not None:
            axis.cw(value)
        assert axis.sw() & 0x7F == bits, hex(axis.sw())


def test_transition_table_covers_cia402() -> None:
    """CiA 402 transitions 2-12, 15, 16 come from controlword commands; 3+4 in one step for 0x0F."""
    numbers = {n for _, n in TRANSITIONS.values()}
    assert numbers == {2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 15, 16}
    assert decode_command(0x80, 0x00) is Command.FAULT_RESET
    assert decode_command(0x80, 0x80) is None              # only the rising edge resets
    assert next_state(PdsState.OPERATION_ENABLED, decode_command(0x07, 0x0F)) == (PdsState.SWITCHED_ON, 5)
    assert next_state(PdsState.FAULT, decode_command(0x0F, 0)) is None


def test_pv_reaches_velocity_and_speed_zero_bit(axis: Axis) -> None:
    """PV (mode 3): bit 10 once |v - 0x60FF| <= 0x606D for 0x606E ms; bit 12 'speed = 0'."""
    axis.enable(3)
    assert axis.sw() & 0x1000
    axis.w(0x60FF, 0, "i", 30_000)
    t0 = axis.clock.now()
    axis.clock.advance(0.002)
    assert not axis.sw() & 0x400
    t = axis.until(lambda: bool(axis.sw() & 0x400), 1.0)
    assert 0.07 < t - t0 < 0.2          # 30000 inc/s at 409600 inc/s^2: 73 ms ramp + window time
    assert not axis.sw() & 0x1000
    assert abs(axis.r(0x606C) - 30_000) <= 100


def test_csv_clamps_to_max_profile_velocity(axis: Axis) -> None:
    """CSV (mode 9): 0x60FF beyond 0x607F is limited; statusword bit 11 internal limit active."""
    axis.w(0x607F, 0, "I", 10_000)
    axis.enable(9)
    axis.w(0x60FF, 0, "i", 50_000)
    axis.clock.advance(0.3)
    assert abs(axis.r(0x606C) - 10_000) <= 20
    assert axis.sw() & 0x800


def test_pp_halt_and_relative_and_buffered_setpoints(axis: Axis) -> None:
    """PP: halt (bit 8) stops with 0x6084 and reports target reached; relative moves (bit 6) add
    to the last target; with bit 5 = 0 a second set-point waits for the first."""
    axis.enable(1)
    axis.w(0x607A, 0, "i", 100_000)
    axis.cw(0x1F)
    axis.cw(0x0F)
    axis.clock.advance(0.3)
    axis.cw(0x10F)                                   # halt
    axis.until(lambda: axis.r(0x606C) == 0 and bool(axis.sw() & 0x400), 0.5)
    halted_at = axis.r(0x6064)
    assert 0 < halted_at < 100_000
    axis.cw(0x0F)                                    # halt released: the move to 100000 resumes
    axis.w(0x607A, 0, "i", 1_000)
    axis.cw(0x7F)                                    # relative + change immediately: 101000
    assert axis.sw() & 0x1000                        # set-point acknowledged
    axis.cw(0x0F)
    assert axis.drive.target == 101_000
    axis.w(0x607A, 0, "i", 5_000)
    axis.cw(0x1F)                                    # bit 5 = 0: buffered until 101000 is reached
    assert axis.sw() & 0x1000
    axis.cw(0x0F)
    axis.until(lambda: axis.drive.target == 5_000, 5.0)
    assert abs(axis.r(0x6064) - 101_000) <= 10
    axis.until(lambda: bool(axis.sw() & 0x400), 5.0)
    assert abs(axis.r(0x6064) - 5_000) <= 10


def test_homing_positive_limit_switch_and_halt(axis: Axis) -> None:
    """Homing method 18 (positive limit switch): the falling edge of the switch at +150000 inc
    becomes 0x30B0; halt (bit 8) interrupts a homing run (statusword 'interrupted')."""
    axis.w(0x6098, 0, "b", 18)
    axis.w(0x6099, 1, "I", 200_000)
    axis.w(0x6099, 2, "I", 10_000)
    axis.w(0x609A, 0, "I", 4_096_000)
    axis.w(0x30B0, 0, "i", 7)
    axis.enable(6)
    axis.cw(0x1F)
    axis.until(lambda: axis.sw() & 0x3400 == 0x1400, 3.0)
    assert axis.drive.homing is not None and axis.drive.homing.home_physical is not None
    assert 149_990 <= axis.drive.homing.home_physical <= 150_000
    assert 7 - 200 < axis.r(0x6064) < 7
    axis.cw(0x0F)
    axis.w(0x6098, 0, "b", 17)
    axis.cw(0x1F)
    axis.clock.advance(0.1)
    assert axis.sw() & 0x3400 == 0x0000              # in progress
    axis.cw(0x11F)
    assert axis.sw() & 0x3400 == 0x0400              # interrupted
    with pytest.raises(SdoAbort) as exc:
        axis.w(0x6098, 0, "b", 1)
    assert exc.value.code == 0x06090030


def test_quick_stop_option_2_ends_switch_on_disabled(axis: Axis) -> None:
    """Quick stop option code 2: ramp down with 0x6085, then 'switch on disabled' (CiA 402)."""
    axis.w(0x605A, 0, "h", 2)
    axis.enable(3)
    axis.w(0x60FF, 0, "i", 20_000)
    axis.clock.advance(0.2)
    axis.cw(0x02)
    assert state_from_statusword(axis.sw()) is PdsState.QUICK_STOP_ACTIVE
    axis.clock.advance(0.02)
    assert state_from_statusword(axis.sw()) is PdsState.SWITCH_ON_DISABLED


def test_following_error_window_disabled(axis: Axis) -> None:
    """0x6065 = 0xFFFFFFFF switches following error supervision off: a blocked axis never faults."""
    axis.w(0x6065, 0, "I", 0xFFFFFFFF)
    axis.enable(1)
    axis.drive.plant.external_torque = -6000.0
    axis.clock.advance(0.5)
    assert state_from_statusword(axis.sw()) is PdsState.OPERATION_ENABLED
    assert axis.r(0x60F4) > 1_000


def test_event_tpdo1_follows_statusword_in_operational(axis: Axis) -> None:
    """TPDO1 (statusword + position actual, type 255) is sent on change in NMT Operational, with
    bit 9 remote set (IDX guide table 3-11)."""
    axis.drive.node.nmt_command(NmtCommand.START_REMOTE_NODE)
    axis.clock.advance(0.01)
    axis.frames.clear()
    axis.cw(0x06)
    axis.clock.advance(0.01)
    tpdo = [f.data for f in axis.frames if f.can_id == 0x183]
    assert tpdo == [struct.pack("<Hi", 0x0231, 0)]


def test_unconfigured_drive_is_silent_until_lss() -> None:
    """An unconfigured drive (node-ID 0xFF) sends no boot-up and answers no SDO (CiA 305)."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0")
    frames: list[CanFrame] = []
    bus.add_monitor(lambda f, t: frames.append(f))
    d = Drive(clock, bus, None, 0x1009)
    d.start()
    probe = bus.attach("probe")
    probe.send(CanFrame(0x600 + 1, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])))
    clock.advance(0.1)
    assert [f.can_id for f in frames] == [0x601]
    assert d.node.node_id is None


def test_transition_16_resumes_the_motion(axis: Axis) -> None:
    """CiA 402 transition 16 (quick stop active -> operation enabled, quick stop option codes
    5..8): the drive function is enabled again: in PV the axis runs up to 0x60FF again."""
    axis.w(0x605A, 0, "h", 6)
    axis.enable(3)
    axis.w(0x60FF, 0, "i", 20_000)
    axis.clock.advance(0.3)
    axis.cw(0x02)                                    # quick stop
    axis.clock.advance(0.3)
    assert state_from_statusword(axis.sw()) is PdsState.QUICK_STOP_ACTIVE
    assert abs(axis.r(0x606C)) <= 5
    axis.cw(0x0F)                                    # enable operation: transition 16
    assert state_from_statusword(axis.sw()) is PdsState.OPERATION_ENABLED
    axis.clock.advance(0.3)
    assert abs(axis.r(0x606C) - 20_000) <= 100


def test_actual_values_reach_dictionary_subscribers(axis: Axis) -> None:
    """The drive publishes its actual values through the dictionary's change notification (the
    mechanism event-driven TPDOs use, CiA 301 7.2.2): a subscriber of 0x6064 position actual
    value sees every change, the last one equal to the stored value."""
    seen: list[int] = []
    axis.drive.od.subscribe((0x6064, 0), lambda key, value: seen.append(value))
    axis.enable(3)
    axis.w(0x60FF, 0, "i", 20_000)
    axis.clock.advance(0.1)
    assert len(seen) > 50
    assert seen[-1] == axis.r(0x6064)
    assert all(a != b for a, b in itertools.pairwise(seen))
