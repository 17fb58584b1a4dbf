"""The profile position set-point handshake of the drive for every way controlword bit 4 goes down or the
set-point is dropped, on the simulated clock (node.write = what an SDO download does).

CiA 402-2 (IEC 61800-7-201) profile position mode, set-point transmission: "After data is applied to the
drive, the host signals that the data is valid by changing bit 4 (new set-point) from 0 to 1 in the
controlword. The drive responds with set-point acknowledge (bit 12 set to 1 in the statusword) after it
recognised and buffered the new valid data. Now the host may release the new set-point bit and afterwards
the drive signals with set-point acknowledge = 0 its ability to accept new data." The set-point is taken
on the rising edge of bit 4 in 'operation enabled' only; bits 12/13 of the statusword are
operation-mode specific and the states' own bits (0-6) follow the CiA 402 statusword table.
"""

from __future__ import annotations

import struct
from pathlib import Path

import canopen
import pytest

from gatewaylab.bus import VirtualBus
from gatewaylab.canopen.cia402 import PdsState, state_from_statusword
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.rig.process import RigProcess

ACK = 0x1000          # statusword bit 12: set-point acknowledge (PP)


class Axis:
    """Drive 3 alone on a bus with a master that acknowledges its frames, NMT pre-operational."""

    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.bus = VirtualBus(self.clock, "can0")
        self.master = self.bus.attach("master")
        self.drive = Drive(self.clock, self.bus, 3, 0x1003)
        self.drive.start()
        self.clock.advance(0.01)

    def w(self, index: int, sub: int, fmt: str, value: int) -> None:
        self.drive.node.write(index, sub, struct.pack("<" + fmt, value))

    def cw(self, value: int) -> None:
        self.w(0x6040, 0, "H", value)

    def sw(self) -> int:
        return int(self.drive.node.get(0x6041, 0))

    def state(self) -> PdsState:
        return state_from_statusword(self.sw())

    def moving_with_ack(self, target: int = 1000, settle: float = 0.0) -> None:
        """PP, operation enabled, a set-point taken with 0x1F (bit 4 still held)."""
        self.w(0x6060, 0, "b", 1)
        for value in (0x06, 0x07, 0x0F):
            self.cw(value)
        self.w(0x607A, 0, "i", target)
        self.cw(0x1F)
        assert self.sw() & ACK, "set-point not acknowledged"
        self.clock.advance(settle)


@pytest.fixture
def axis() -> Axis:
    return Axis()


def test_disable_voltage_from_a_new_setpoint_clears_the_acknowledge(axis: Axis) -> None:
    """The reported sequence: 0x1F -> 0x00 (transition 9) -> 0x06 (2) -> 0x07 (3). Bit 4 is released with
    the disable voltage command, so bit 12 is 0 (CiA 402-2 set-point transmission, quoted above); the
    state bits are 'switch on disabled' 0x0040, 'ready to switch on' 0x0021 + voltage enabled 0x0010,
    'switched on' 0x0023 + 0x0010; bit 10 'target reached' stays as the move left it (reached)."""
    axis.moving_with_ack(1000, settle=0.5)
    words = []
    for value in (0x00, 0x06, 0x07):
        axis.cw(value)
        words.append(axis.sw())
    assert [hex(w) for w in words] == ["0x440", "0x431", "0x433"]


def test_new_setpoint_released_in_operation_enabled(axis: Axis) -> None:
    """0x1F -> 0x0F: bit 4 down, the drive stays in 'operation enabled' and drops bit 12 at once."""
    axis.moving_with_ack()
    axis.cw(0x0F)
    assert axis.state() is PdsState.OPERATION_ENABLED and not axis.sw() & ACK


@pytest.mark.parametrize(("controlword", "state"), [
    (0x07, PdsState.SWITCHED_ON),            # disable operation, transition 5
    (0x06, PdsState.READY_TO_SWITCH_ON),     # shutdown, transition 8
    (0x00, PdsState.SWITCH_ON_DISABLED),     # disable voltage, transition 9
    (0x02, PdsState.QUICK_STOP_ACTIVE),      # quick stop, transition 11 (option 6: stays in quick stop)
])
def test_leaving_operation_enabled_with_bit4_released(axis: Axis, controlword: int, state: PdsState) -> None:
    """Every command out of 'operation enabled' whose controlword has bit 4 = 0: bit 12 = 0 in the new state
    (the handshake follows bit 4 in every state, not only in 'operation enabled')."""
    axis.moving_with_ack()
    axis.cw(controlword)
    assert axis.state() is state
    assert not axis.sw() & ACK, hex(axis.sw())


@pytest.mark.parametrize(("controlword", "state"), [
    (0x17, PdsState.SWITCHED_ON),            # disable operation + bit 4 held, transition 5
    (0x16, PdsState.READY_TO_SWITCH_ON),     # shutdown + bit 4 held, transition 8
    (0x10, PdsState.SWITCH_ON_DISABLED),     # disable voltage + bit 4 held, transition 9
])
def test_leaving_operation_enabled_drops_the_setpoint(axis: Axis, controlword: int, state: PdsState) -> None:
    """Bit 4 held while the drive leaves 'operation enabled' for a state without power: the trajectory
    generator has no set-point any more (enabling again starts from the actual position), so bit 12
    ('trajectory generator has assumed the positioning values') is 0. Enabling again with bit 4 still
    held takes no set-point: only a 0 -> 1 edge of bit 4 does (CiA 402-2 set-point transmission)."""
    axis.moving_with_ack()
    axis.cw(controlword)
    assert axis.state() is state and not axis.sw() & ACK, hex(axis.sw())
    for value in (0x16, 0x17, 0x1F)[(0x10, 0x16, 0x17).index(controlword):]:
        axis.cw(value)
    assert axis.state() is PdsState.OPERATION_ENABLED
    assert not axis.sw() & ACK and axis.drive.target is None
    axis.cw(0x0F)
    axis.cw(0x1F)                                 # a fresh edge: taken and acknowledged
    assert axis.sw() & ACK and axis.drive.target == 1000


def test_quick_stop_keeps_the_setpoint_until_bit4_is_released(axis: Axis) -> None:
    """Quick stop option 6 (0x605A): 'quick stop active' is kept after the ramp and 'enable operation'
    resumes the motion (transition 16), so the acknowledged set-point stays acknowledged while bit 4 is
    held; releasing bit 4 in 'quick stop active' clears bit 12 (the handshake in every state)."""
    axis.moving_with_ack(100_000)
    axis.cw(0x1B)                                 # quick stop, bit 4 held
    assert axis.state() is PdsState.QUICK_STOP_ACTIVE and axis.sw() & ACK
    axis.cw(0x0B)                                 # bit 4 released
    assert axis.state() is PdsState.QUICK_STOP_ACTIVE and not axis.sw() & ACK


def test_quick_stop_ending_in_switch_on_disabled_drops_the_setpoint(axis: Axis) -> None:
    """Quick stop option 2: after the ramp the drive goes to 'switch on disabled' (transition 12) and the
    set-point is gone: bit 12 = 0 although bit 4 is still held."""
    axis.w(0x605A, 0, "h", 2)
    axis.moving_with_ack(100_000, settle=0.2)
    axis.cw(0x1B)
    deadline = axis.clock.now() + 2.0
    while axis.state() is PdsState.QUICK_STOP_ACTIVE:
        assert axis.clock.now() < deadline, "quick stop ramp did not end"
        axis.clock.advance(0.001)
    assert axis.state() is PdsState.SWITCH_ON_DISABLED and not axis.sw() & ACK, hex(axis.sw())


def test_fault_drops_the_setpoint(axis: Axis) -> None:
    """A fault (transitions 13, 14) with bit 4 held: the fault reaction ramps the axis down and the
    set-point is gone, so bit 12 = 0 in 'fault reaction active' and in 'fault'."""
    axis.moving_with_ack(100_000, settle=0.2)
    axis.drive.fault(0x8611, 0x20)
    assert axis.state() is PdsState.FAULT_REACTION_ACTIVE and not axis.sw() & ACK
    axis.clock.advance(1.0)
    assert axis.state() is PdsState.FAULT and not axis.sw() & ACK, hex(axis.sw())


def test_mode_change_drops_the_setpoint(axis: Axis) -> None:
    """A change of 0x6060 restarts the motion from the actual position; back in PP with bit 4 still held
    nothing is acknowledged (no set-point was taken: that needs a 0 -> 1 edge of bit 4)."""
    axis.moving_with_ack()
    axis.w(0x6060, 0, "b", 3)                     # profile velocity
    axis.w(0x6060, 0, "b", 1)                     # back to profile position, bit 4 held
    assert axis.state() is PdsState.OPERATION_ENABLED and not axis.sw() & ACK, hex(axis.sw())


RIG_ONE_DRIVE = """
clock = "realtime"

[[bus]]
name = "can0"

[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
"""


def test_user_path_disable_voltage_after_new_setpoint(tmp_path: Path) -> None:
    """The report as a user sees it: ``gatewaylab run`` with one drive, python ``canopen`` SDO writes of
    0x6060 = 1, 0x06, 0x07, 0x0F, 0x607A, 0x1F (bit 12 set), then 0x00, 0x06, 0x07: bit 12 is 0 in
    'switch on disabled', 'ready to switch on' and 'switched on' (CiA 402-2 set-point transmission: bit 12
    follows bit 4 down; state bits from the CiA 402 statusword table)."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG_ONE_DRIVE)
    with RigProcess(rig_file, workdir=tmp_path) as rig:
        network = canopen.Network()
        network.connect(interface="gatewaylab", channel=rig.endpoint("can0"))
        try:
            node = network.add_node(2, canopen.ObjectDictionary())
            sdo = node.sdo

            def write(index: int, fmt: str, value: int) -> None:
                sdo.download(index, 0, struct.pack("<" + fmt, value))

            def statusword() -> int:
                return int(struct.unpack("<H", sdo.upload(0x6041, 0))[0])

            write(0x6060, "b", 1)
            for value in (0x06, 0x07, 0x0F):
                write(0x6040, "H", value)
            write(0x607A, "i", 1000)
            write(0x6040, "H", 0x1F)
            assert statusword() & ACK
            seen = []
            for value in (0x00, 0x06, 0x07):
                write(0x6040, "H", value)
                seen.append(statusword())
        finally:
            network.disconnect()
    assert [w & (ACK | 0x6F) for w in seen] == [0x0040, 0x0021, 0x0023], [hex(w) for w in seen]
