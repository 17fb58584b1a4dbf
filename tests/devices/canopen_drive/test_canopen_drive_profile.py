"""The IDX-like CiA 402 drive through the python ``canopen`` library (SDO, PDO, BaseNode402).

Issue 3 'IDX-like CiA 402 drive'; IDX guide 3.1 (CiA 402 V4.0), table 3-11 (statusword bit 9),
3.3.3.4 (EMCY), chapter 6 (abort codes).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest
from canopen.sdo import SdoAbortedError

from gatewaylab.bus import CanFrame, VirtualBus, python_can_bus
from gatewaylab.canopen.cia402 import PdsState, state_from_statusword
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.canopen_drive.objects import DEVICE_TYPE, MAXON_VENDOR_ID, PRODUCT_CODE

logging.getLogger("canopen.profiles.p402").setLevel(logging.ERROR)

NODE = 2


class Setup:
    def __init__(self, tmp_path: Path) -> None:
        self.clock = SimulatedClock()
        self.bus = VirtualBus(self.clock, "can0")
        self.trace: list[tuple[float, CanFrame]] = []
        self.bus.add_monitor(lambda f, t: self.trace.append((t, f)))
        self.drive = Drive(self.clock, self.bus, NODE, 0x1002, name="axis2")
        self.drive.start()
        self.clock.advance(0.01)
        eds = tmp_path / "drive.eds"
        eds.write_text(self.drive.node.to_eds())
        self.network = canopen.Network(python_can_bus(self.bus))
        self.network.NOTIFIER_CYCLE = 0.05   # quick shutdown of python-can's notifier thread
        self.network.connect()
        self.node = canopen.BaseNode402(NODE, str(eds))
        self.network.add_node(self.node)

    def sw(self) -> int:
        return int(self.node.sdo[0x6041].raw)

    def advance_until(self, cond, limit: float, step: float = 0.005) -> float:  # type: ignore[no-untyped-def]
        end = self.clock.now() + limit
        while not cond():
            assert self.clock.now() < end, "condition not met in time"
            self.clock.advance(step)
        return self.clock.now()

    def frames(self, cob_id: int) -> list[bytes]:
        return [f.data for _, f in self.trace if f.can_id == cob_id]


@pytest.fixture
def s(tmp_path: Path) -> Iterator[Setup]:
    setup = Setup(tmp_path)
    try:
        yield setup
    finally:
        setup.network.disconnect()


def test_identity_and_maxon_objects(s: Setup) -> None:
    """Issue 3: 0x1018 with maxon's vendor id 0xFB, product code, revision, configurable serial;
    0x1000 servo drive device type; 0x1008 name; maxon 0x2006 (U16 ms, default 500) and
    0x30B0 (I32); 0x6502 lists PP, PV, HM, CSP, CSV, CST."""
    sdo = s.node.sdo
    assert sdo[0x1000].raw == DEVICE_TYPE == 0x00020192
    assert sdo[0x1018][1].raw == MAXON_VENDOR_ID == 0xFB
    assert sdo[0x1018][2].raw == PRODUCT_CODE
    assert sdo[0x1018][4].raw == 0x1002
    assert "IDX" in sdo[0x1008].raw
    assert sdo.upload(0x2006, 0) == (500).to_bytes(2, "little")
    sdo[0x30B0].raw = -12345
    assert sdo[0x30B0].raw == -12345
    assert sdo[0x6502].raw == (1 << 0) | (1 << 2) | (1 << 5) | (1 << 7) | (1 << 8) | (1 << 9)
    with pytest.raises(SdoAbortedError) as exc:
        sdo[0x6041].raw = 0
    assert exc.value.code == 0x06010002            # IDX table 6-20: read only error
    with pytest.raises(SdoAbortedError) as exc:
        sdo[0x6060].raw = 7                        # interpolated position: not supported
    assert exc.value.code == 0x06090030            # value range error
    with pytest.raises(SdoAbortedError) as exc:
        sdo[0x6098].raw = 1                        # homing method not supported
    assert exc.value.code == 0x06090030


def test_default_pdo_mapping(s: Setup) -> None:
    """Issue 3: RPDO1 = controlword + target position, TPDO1 = statusword + position actual."""
    sdo = s.node.sdo
    assert sdo[0x1600][0].raw == 2
    assert sdo[0x1600][1].raw == 0x60400010 and sdo[0x1600][2].raw == 0x607A0020
    assert sdo[0x1A00][1].raw == 0x60410010 and sdo[0x1A00][2].raw == 0x60640020
    assert sdo[0x1400][1].raw == 0x200 + NODE and sdo[0x1800][1].raw == 0x180 + NODE


def test_power_state_machine_to_operation_enabled(s: Setup) -> None:
    """CiA 402 FSA driven by controlword 0x6040, read in statusword 0x6041 (canopen BaseNode402,
    statusword via SDO): switch on disabled -> ready -> switched on -> operation enabled."""
    node = s.node
    assert node.state == "SWITCH ON DISABLED"
    assert s.sw() & 0x6F == 0x40
    node.state = "READY TO SWITCH ON"
    assert s.sw() & 0x6F == 0x21
    node.state = "SWITCHED ON"
    assert s.sw() & 0x6F == 0x23
    node.state = "OPERATION ENABLED"
    assert s.sw() & 0x6F == 0x27
    assert s.drive.state is PdsState.OPERATION_ENABLED
    node.state = "SWITCH ON DISABLED"
    assert s.drive.state is PdsState.SWITCH_ON_DISABLED


def test_remote_bit_follows_nmt_operational(s: Setup) -> None:
    """IDX guide table 3-11 note 3: statusword bit 9 (remote) is TRUE only in NMT Operational."""
    assert not s.sw() & 0x200
    s.node.nmt.state = "OPERATIONAL"
    assert s.sw() & 0x200
    s.node.nmt.state = "PRE-OPERATIONAL"
    assert not s.sw() & 0x200


def pp_move(s: Setup, target: int) -> tuple[float, int, list[int]]:
    node = s.node
    node.state = "OPERATION ENABLED"
    node.sdo[0x6060].raw = 1
    node.sdo[0x607A].raw = target
    node.controlword = 0x1F            # new set-point (bit 4), absolute
    assert s.sw() & 0x1000             # set-point acknowledge
    node.controlword = 0x0F
    samples: list[int] = []

    def reached() -> bool:
        samples.append(int(node.sdo[0x6064].raw))
        return bool(s.sw() & 0x400)

    t = s.advance_until(reached, 5.0, 0.05)
    return t, int(node.sdo[0x6064].raw), samples


def test_pp_move_lands_repeatably(s: Setup, tmp_path: Path) -> None:
    """Profile position (CiA 402 PP): a move to 50000 inc at 40960 inc/s, 409600 inc/s^2 sets
    'target reached' (bit 10) with the actual position inside the position window 0x6067; a
    second drive given the same commands produces the very same numbers."""
    t, pos, samples = pp_move(s, 50_000)
    assert abs(pos - 50_000) <= s.node.sdo[0x6067].raw
    # trapezoid: 0.1 s ramps, 50000/40960 s cruise-equivalent -> done after about 1.32 s
    assert 1.3 < t - 0.01 < 1.5
    assert samples == sorted(samples)             # no overshoot backwards on the way
    s.clock.advance(0.5)
    assert abs(s.node.sdo[0x6064].raw - 50_000) <= 1
    other = Setup(tmp_path / "b" if (tmp_path / "b").mkdir() is None else tmp_path)
    try:
        t2, pos2, samples2 = pp_move(other, 50_000)
    finally:
        other.network.disconnect()
    assert (t2, pos2, samples2) == (t, pos, samples)


def test_pp_software_position_limit(s: Setup) -> None:
    """CiA 402 0x607D: a target beyond the software limit is clamped; bit 11 internal limit."""
    s.node.sdo[0x607D][2].raw = 20_000
    s.node.state = "OPERATION ENABLED"
    s.node.sdo[0x607A].raw = 30_000
    s.node.controlword = 0x1F
    s.node.controlword = 0x0F
    assert s.sw() & 0x800
    s.advance_until(lambda: bool(s.sw() & 0x400), 3.0, 0.05)
    assert abs(s.node.sdo[0x6064].raw - 20_000) <= 10


def test_pp_new_set_point_in_rpdo1_takes_the_target_of_the_same_pdo(s: Setup) -> None:
    """CiA 402 profile position: the new set-point bit (controlword bit 4) takes the target position 0x607A;
    with the default RPDO1 (controlword + target position, docs/canopen-drive.md) a master sends both in one
    PDO, and the drive must move to that PDO's target (issue 21: it took the previous target, 0, and reported
    'target reached' at once -- the controlword was applied before the target of the same frame)."""
    node = s.node
    node.nmt.state = "OPERATIONAL"
    node.state = "OPERATION ENABLED"
    node.sdo[0x6060].raw = 1
    rpdo1 = 0x200 + NODE
    s.network.send_message(rpdo1, (0x1F).to_bytes(2, "little") + (4000).to_bytes(4, "little", signed=True))
    s.advance_until(lambda: bool(s.sw() & 0x1000), 1.0)                       # set-point acknowledge
    s.network.send_message(rpdo1, (0x0F).to_bytes(2, "little") + (4000).to_bytes(4, "little", signed=True))
    s.advance_until(lambda: bool(s.sw() & 0x400) and abs(node.sdo[0x6064].raw - 4000) <= 10, 3.0, 0.05)


def test_homing_current_position_with_base_node_402(s: Setup) -> None:
    """Homing mode 6, method 37 (current position): canopen's BaseNode402.homing() succeeds and
    the position actual value becomes the maxon home position 0x30B0."""
    s.node.sdo[0x30B0].raw = 1000
    s.node.sdo[0x6098].raw = 37
    assert s.node.homing(timeout=5)
    assert s.node.sdo[0x6064].raw == 1000
    assert s.node.op_mode == "HOMING"
    assert s.sw() & 0x3400 == 0x1400        # target reached + homing attained


def test_homing_negative_limit_switch(s: Setup) -> None:
    """Homing method 17 (negative limit switch, CiA 402): search negative at 0x6099:01 until the
    switch, leave it at 0x6099:02; the edge becomes 0x30B0. BaseNode402.homing() runs in a
    thread while the test moves simulated time."""
    sdo = s.node.sdo
    sdo[0x6098].raw = 17
    sdo[0x6099][1].raw = 100_000
    sdo[0x30B0].raw = -500
    result: list[bool] = []
    worker = threading.Thread(target=lambda: result.append(s.node.homing(timeout=30)))
    worker.start()
    while worker.is_alive():
        with s.clock.lock:           # the worker's SDO requests also run the simulation
            s.clock.advance(0.002)
    assert result == [True]
    # the switch sits at -150000 inc of the axis; the edge is where it becomes inactive again
    assert s.drive.plant.digital_inputs() & 1 == 0
    edge_user = -500
    pos = int(sdo[0x6064].raw)
    assert edge_user < pos < edge_user + 200        # stopped just past the edge (zero search speed)
    assert s.drive.offset == pytest.approx(-500 - s.drive.homing.home_physical)  # type: ignore[union-attr]
    assert -150_001 <= s.drive.homing.home_physical <= -149_990  # type: ignore[union-attr]


def test_following_error_fault_and_emcy(s: Setup) -> None:
    """CiA 402 0x6065/0x6066: a following error beyond the window for longer than the timeout
    faults the drive (statusword fault bit 3, 0x603F = 0x8611) and sends one EMCY (IDX guide
    3.3.3.4) with the error register; fault reset (bit 7 edge) clears it with an 'error reset'."""
    node = s.node
    node.state = "OPERATION ENABLED"
    s.trace.clear()
    s.drive.plant.external_torque = -6000.0      # twice the torque limit: the axis is pushed away
    s.advance_until(lambda: bool(s.sw() & 0x08), 1.0, 0.01)
    s.advance_until(lambda: state_from_statusword(s.sw()) is PdsState.FAULT, 0.5, 0.01)
    assert node.sdo[0x603F].raw == 0x8611
    assert node.sdo[0x1001].raw & 0x21 == 0x21
    emcy = s.frames(0x80 + NODE)
    assert emcy == [bytes.fromhex("11 86 21 00 00 00 00 00")]
    s.drive.plant.external_torque = 0.0
    node.controlword = 0x80
    assert node.state == "SWITCH ON DISABLED"
    assert node.sdo[0x603F].raw == 0
    assert s.frames(0x80 + NODE)[-1] == bytes(8)   # 'error reset / no error', register 0


def test_quick_stop_and_transition_16(s: Setup) -> None:
    """CiA 402 quick stop (controlword 0x0002) in profile velocity: the drive ramps down with the
    quick stop deceleration 0x6085 and stays in 'quick stop active' (option code 6); enable
    operation (transition 16) resumes."""
    node = s.node
    node.state = "OPERATION ENABLED"
    node.sdo[0x6060].raw = 3
    node.sdo[0x60FF].raw = 20_000
    s.advance_until(lambda: bool(s.sw() & 0x400), 1.0)     # velocity reached
    assert abs(node.sdo[0x606C].raw - 20_000) <= 100
    node.controlword = 0x02
    assert node.state == "QUICK STOP ACTIVE"
    s.clock.advance(0.01)
    assert abs(node.sdo[0x6062].raw - s.drive.demand) < 1   # demand ramp ended after 5 ms
    assert abs(node.sdo[0x606C].raw) < 2_000
    s.clock.advance(0.3)
    assert abs(node.sdo[0x606C].raw) <= 5
    assert node.state == "QUICK STOP ACTIVE"
    node.controlword = 0x0F
    assert node.state == "OPERATION ENABLED"


def test_csp_with_sync_rpdo_tpdo(s: Setup) -> None:
    """Cyclic synchronous position (mode 8) as a master runs it: RPDO1 (controlword + target
    position) and TPDO1 (statusword + position actual) synchronous (type 1) on every SYNC."""
    node = s.node
    node.tpdo.read()
    node.rpdo.read()
    node.tpdo[1].trans_type = 1
    node.tpdo[1].save()
    node.rpdo[1].trans_type = 1
    node.rpdo[1].save()
    node.sdo[0x6060].raw = 8
    node.state = "OPERATION ENABLED"
    node.nmt.state = "OPERATIONAL"
    s.trace.clear()
    target = 0
    start = s.clock.now()
    for k in range(300):
        target += 40                                      # 40 inc per ms = 40000 inc/s
        node.rpdo[1]["Controlword"].raw = 0x0F
        node.rpdo[1]["Target position"].raw = target
        node.rpdo[1].transmit()
        s.network.send_message(0x80, b"")                 # SYNC
        s.clock.run_until(start + (k + 1) * 0.001)        # a 1 ms master cycle
    tpdos = s.frames(0x180 + NODE)
    assert len(tpdos) == 300
    sw = int.from_bytes(tpdos[-1][:2], "little")
    pos = int.from_bytes(tpdos[-1][2:6], "little", signed=True)
    assert sw & 0x6F == 0x27 and sw & 0x1000 and sw & 0x200   # OE, following, remote
    assert abs(pos - target) < 100


def test_cyclic_torque_and_velocity(s: Setup) -> None:
    """CST (10): constant torque accelerates the axis; CSV (9): the axis runs at 0x60FF."""
    node = s.node
    node.sdo[0x6060].raw = 10
    node.state = "OPERATION ENABLED"
    node.sdo[0x6071].raw = 100
    s.clock.advance(0.05)
    v1 = node.sdo[0x606C].raw
    s.clock.advance(0.05)
    assert node.sdo[0x606C].raw > v1 > 0
    assert abs(node.sdo[0x6077].raw - 100) <= 1
    node.sdo[0x6060].raw = 9
    node.sdo[0x60FF].raw = -10_000
    s.clock.advance(0.3)
    assert abs(node.sdo[0x606C].raw + 10_000) <= 20


def test_reset_node_disables_the_drive(s: Setup) -> None:
    """IDX guide table 3-11: reset node has the effect of a power cycle: the power stage is off
    again (switch on disabled) and the boot-up message is sent."""
    s.node.state = "OPERATION ENABLED"
    s.trace.clear()
    s.node.nmt.send_command(0x81)
    assert s.frames(0x700 + NODE) == [b"\x00"]
    assert s.node.state == "SWITCH ON DISABLED"
