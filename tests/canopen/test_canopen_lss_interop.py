"""LSS slave of the drive against the python ``canopen`` LSS master and our own LssMaster.

IDX guide 3.5 (Layer Setting Services), table 3-14; frames per CiA 305 V3.0.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest
from canopen.lss import LssError as CanopenLssError
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame, VirtualBus, python_can_bus
from gatewaylab.canopen.lss import (
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    Cs,
    LssAddress,
    LssError,
    LssMaster,
    LssState,
    LssTimeout,
)
from gatewaylab.canopen.nmt import NmtCommand, NmtState
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.canopen_drive.objects import MAXON_VENDOR_ID, PRODUCT_CODE, REVISION

SERIALS = (0x1001, 0x1002, 0x1004)


class Rig:
    def __init__(self, tmp_path: Path) -> None:
        self.clock = SimulatedClock()
        self.bus = VirtualBus(self.clock, "can0")
        self.tmp_path = tmp_path
        self.trace: list[CanFrame] = []
        self.bus.add_monitor(lambda frame, t: self.trace.append(frame))
        self.drives: list[Drive] = []

    def drive(self, node_id: int | None, serial: int) -> Drive:
        d = Drive(self.clock, self.bus, node_id, serial, store_path=self.tmp_path / f"drive{serial:x}.json")
        d.start()
        self.drives.append(d)
        return d

    def lss_answers(self) -> list[str]:
        return [f.data.hex(" ").upper() for f in self.trace if f.can_id == LSS_SLAVE_COB_ID]


@pytest.fixture
def rig(tmp_path: Path) -> Rig:
    return Rig(tmp_path)


@pytest.fixture
def network(rig: Rig) -> Iterator[canopen.Network]:
    net = canopen.Network(python_can_bus(rig.bus))
    net.NOTIFIER_CYCLE = 0.05          # quick shutdown of python-can's notifier thread
    net.connect()
    # Answers arrive through python-can's notifier thread; a missing answer costs this timeout.
    net.lss.RESPONSE_TIMEOUT = 0.15
    try:
        yield net
    finally:
        net.disconnect()


def test_fast_scan_finds_every_unconfigured_drive(rig: Rig, network: canopen.Network) -> None:
    """IDX guide 3.5 + table 3-14 'LSS Fastscan': canopen's fast_scan finds the unconfigured drives
    (node-ID 0xFF) one by one; each gets a node-ID (3.5.2.3), stores it (3.5.2.6) and, switched
    back to waiting, boots with it. A configured drive never takes part."""
    unconfigured = [rig.drive(None, s) for s in SERIALS]
    configured = rig.drive(5, 0x2000)
    rig.clock.advance(0.01)
    assert all(d.node.node_id is None and d.node.nmt_state is NmtState.INITIALISING for d in unconfigured)
    found: list[list[int]] = []
    for new_id in (10, 11, 12):
        ok, address = network.lss.fast_scan()
        assert ok, f"fast_scan found nothing while looking for node {new_id}"
        found.append(address)
        network.lss.configure_node_id(new_id)
        network.lss.store_configuration()
        network.lss.send_switch_state_global(network.lss.WAITING_STATE)
    ok, _ = network.lss.fast_scan()
    assert not ok
    assert sorted(a[3] for a in found) == sorted(SERIALS)
    assert all(a[:3] == [MAXON_VENDOR_ID, PRODUCT_CODE, REVISION] for a in found)
    ids = {d.serial: d.node.node_id for d in unconfigured}
    assert sorted(ids.values()) == [10, 11, 12]
    for d in unconfigured:
        assert d.node.nmt_state is NmtState.PRE_OPERATIONAL
        # boot-up message 0x700 + id with data 00 (CiA 301) after the reset communication
        assert CanFrame(0x700 + d.node.node_id, b"\x00") in rig.trace
    assert configured.node.node_id == 5
    # the stored node-ID survives a power cycle (IDX guide 3.5.2.6 'non-volatile memory')
    d0 = unconfigured[0]
    d0.stop()
    again = Drive(rig.clock, rig.bus, None, d0.serial, store_path=d0.store_path)
    assert again.node.node_id == ids[d0.serial]


def test_selective_switch_and_inquire(rig: Rig, network: canopen.Network) -> None:
    """IDX guide 3.5.2.2 and 3.5.2.7-3.5.2.11: switch one drive selectively into configuration and
    read its identity and node-ID; LSS only answers in NMT Stopped (IDX guide 3.5)."""
    d = rig.drive(7, 0x1002)
    rig.drive(8, 0x1003)
    rig.clock.advance(0.01)
    with pytest.raises(CanopenLssError):   # pre-operational: LSS is not accessible
        network.lss.send_switch_state_selective(MAXON_VENDOR_ID, PRODUCT_CODE, REVISION, 0x1002)
    network.nmt.state = "STOPPED"
    assert d.node.nmt_state is NmtState.STOPPED
    assert network.lss.send_switch_state_selective(MAXON_VENDOR_ID, PRODUCT_CODE, REVISION, 0x1002)
    assert d.lss.state is LssState.CONFIGURATION
    assert network.lss.inquire_node_id() == 7
    assert network.lss.inquire_lss_address(Cs.INQUIRE_VENDOR) == MAXON_VENDOR_ID
    assert network.lss.inquire_lss_address(Cs.INQUIRE_PRODUCT) == PRODUCT_CODE
    assert network.lss.inquire_lss_address(Cs.INQUIRE_REVISION) == REVISION
    assert network.lss.inquire_lss_address(Cs.INQUIRE_SERIAL) == 0x1002
    # configure node-ID: 0 is out of range (error 1), 0x22 accepted but only active after reset
    with pytest.raises(CanopenLssError):
        network.lss.configure_node_id(0)
    network.lss.configure_node_id(0x22)
    network.lss.send_switch_state_global(network.lss.WAITING_STATE)
    assert d.node.node_id == 7
    network.nmt.send_command(0x82)   # NMT reset communication (IDX table 3-12)
    assert d.node.node_id == 0x22
    assert CanFrame(0x700 + 0x22, b"\x00") in rig.trace


def test_identify_remote_and_non_configured(rig: Rig, network: canopen.Network) -> None:
    """IDX guide 3.5.2.12: slaves inside the revision/serial ranges answer cs 0x4F;
    3.5.2.13: slaves without node-ID answer cs 0x50."""
    rig.drive(None, 0x1001)
    rig.drive(None, 0x1002)
    rig.drive(None, 0x1010)
    rig.clock.advance(0.01)
    network.lss.send_identify_remote_slave(MAXON_VENDOR_ID, PRODUCT_CODE, 0, 0xFFFFFFFF, 0x1000, 0x1002)
    assert rig.lss_answers() == ["4F 00 00 00 00 00 00 00"] * 2
    rig.trace.clear()
    network.lss.send_identify_non_configured_remote_slave()
    assert rig.lss_answers() == ["50 00 00 00 00 00 00 00"] * 3


def test_bit_timing_switch_changes_controller_bitrate(rig: Rig, network: canopen.Network) -> None:
    """IDX guide 3.5.2.4/3.5.2.5: configure bit timing (table index 2 = 500 kbit/s), activate with
    a switch delay: silent at once, new bit rate after one delay, sending after the second."""
    d = rig.drive(3, 0x1002)
    rig.clock.advance(0.01)
    network.nmt.state = "STOPPED"
    network.lss.send_switch_state_global(network.lss.CONFIGURATION_STATE)
    with pytest.raises(CanopenLssError):
        network.lss.configure_bit_timing(5)        # reserved in the CiA 305 table
    network.lss.configure_bit_timing(2)
    assert d.node.controller.bitrate == 1_000_000   # not before activation
    network.lss.activate_bit_timing(100)
    rig.clock.advance(0.05)
    assert d.node.controller.bitrate == 1_000_000 and not d.node.controller.connected
    rig.clock.advance(0.06)
    assert d.node.controller.bitrate == 500_000 and not d.node.controller.connected
    rig.clock.advance(0.1)
    assert d.node.controller.connected
    # the master side follows: the bus (and python-can's controller) now run at 500 kbit/s
    rig.bus.bitrate = 500_000
    for c in rig.bus.controllers:
        c.bitrate = 500_000
    assert network.lss.inquire_node_id() == 3


def lss_master(rig: Rig) -> LssMaster:
    ctrl = rig.bus.attach("lss-master")
    master = LssMaster(rig.clock, ctrl.send, timeout=0.01)
    ctrl.on_frame = master.on_frame
    return master


def run(rig: Rig, submit) -> object:  # type: ignore[no-untyped-def]
    results: list[object] = []
    submit(results.append)
    rig.clock.run_while(lambda: not results, max_events=10_000_000)
    return results[0]


def test_own_master_fastscan_assigns_ids(rig: Rig) -> None:
    """Our sans-I/O LssMaster runs CiA 305 Fastscan on the simulated clock only (no threads):
    every unconfigured drive is found in ascending LSS address order and configured."""
    drives = [rig.drive(None, s) for s in (0x3003, 0x1001, 0x2002)]
    m = lss_master(rig)
    assigned = []
    for node_id in (20, 21, 22):
        addr = run(rig, m.fast_scan)
        assert isinstance(addr, LssAddress)
        assigned.append(addr.serial)
        assert run(rig, lambda cb, n=node_id: m.configure_node_id(n, cb)) is None
        assert run(rig, m.store_configuration) is None
        run(rig, lambda cb: m.switch_state_global(LssState.WAITING, cb))
    assert run(rig, m.fast_scan) is None
    assert assigned == [0x1001, 0x2002, 0x3003]
    assert {d.serial: d.node.node_id for d in drives} == {0x1001: 20, 0x2002: 21, 0x3003: 22}
    assert run(rig, m.identify_non_configured) == 0


def test_own_master_services(rig: Rig) -> None:
    """Our LssMaster: selective switch, inquire, identify ranges, refused configure (error 1) and
    a timeout when nobody answers (IDX guide 3.5.2)."""
    rig.drive(None, 0x1002)
    rig.drive(None, 0x1003)
    m = lss_master(rig)
    assert run(rig, lambda cb: m.identify_remote_slave(MAXON_VENDOR_ID, PRODUCT_CODE, 0, 0xFFFFFFFF,
                                                        0x1000, 0x1FFF, cb)) == 2
    addr = LssAddress(MAXON_VENDOR_ID, PRODUCT_CODE, REVISION, 0x1003)
    assert run(rig, lambda cb: m.switch_state_selective(addr, cb)) is True
    assert run(rig, lambda cb: m.inquire(Cs.INQUIRE_SERIAL, cb)) == 0x1003
    assert run(rig, lambda cb: m.inquire(Cs.INQUIRE_NODE_ID, cb)) == 0xFF
    err = run(rig, lambda cb: m.configure_node_id(200, cb))
    assert isinstance(err, LssError) and err.code == 1
    run(rig, lambda cb: m.switch_state_global(LssState.WAITING, cb))
    assert isinstance(run(rig, lambda cb: m.inquire(Cs.INQUIRE_SERIAL, cb)), LssTimeout)
    missing = LssAddress(MAXON_VENDOR_ID, PRODUCT_CODE, REVISION, 0x9999)
    assert run(rig, lambda cb: m.switch_state_selective(missing, cb)) is False


def test_master_golden_frames(rig: Rig) -> None:
    """CiA 305 request layouts as the master puts them on 0x7E5 (IDX guide figs. 3-25..3-38)."""
    sent: list[str] = []
    m = LssMaster(rig.clock, lambda f: sent.append(f"{f.can_id:03X} " + f.data.hex(" ").upper()))
    m.switch_state_global(LssState.CONFIGURATION)
    m.configure_node_id(5)
    m.configure_bit_timing(3)
    m.activate_bit_timing(1000)
    m.store_configuration()
    m.inquire(Cs.INQUIRE_NODE_ID)
    m.identify_non_configured()
    m.fast_scan()
    m.switch_state_selective(LssAddress(0xFB, 0x61500000, 0x00010000, 0x1002))
    m.identify_remote_slave(0xFB, 0x61500000, 1, 2, 0x1000, 0x1FFF)
    m.inquire(Cs.INQUIRE_VENDOR)
    rig.clock.advance(5.0)
    assert sent[-11:] == [
        "7E5 40 FB 00 00 00 00 00 00",
        "7E5 41 00 00 50 61 00 00 00",
        "7E5 42 00 00 01 00 00 00 00",
        "7E5 43 02 10 00 00 00 00 00",
        "7E5 46 FB 00 00 00 00 00 00",
        "7E5 47 00 00 50 61 00 00 00",
        "7E5 48 01 00 00 00 00 00 00",
        "7E5 49 02 00 00 00 00 00 00",
        "7E5 4A 00 10 00 00 00 00 00",
        "7E5 4B FF 1F 00 00 00 00 00",
        "7E5 5A 00 00 00 00 00 00 00",
    ]
    assert sent[:8] == [
        "7E5 04 01 00 00 00 00 00 00",
        "7E5 11 05 00 00 00 00 00 00",
        "7E5 13 00 03 00 00 00 00 00",
        "7E5 15 E8 03 00 00 00 00 00",
        "7E5 17 00 00 00 00 00 00 00",
        "7E5 5E 00 00 00 00 00 00 00",
        "7E5 4C 00 00 00 00 00 00 00",
        "7E5 51 00 00 00 00 80 00 00",
    ]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=8), min_size=1, max_size=25), st.booleans())
def test_random_lss_frames_on_the_bus(frames: list[bytes], configured: bool) -> None:
    """Random frames on 0x7E5 to a drive (Stopped or unconfigured) only produce 8-byte LSS answers
    with a response cs of table 3-14, or silence; the drive keeps working."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0")
    answers: list[CanFrame] = []
    bus.add_monitor(lambda f, t: answers.append(f) if f.can_id == LSS_SLAVE_COB_ID else None)
    d = Drive(clock, bus, 4 if configured else None, 0x1002)
    d.start()
    if configured:
        d.node.nmt_command(NmtCommand.STOP_REMOTE_NODE)
    ctrl = bus.attach("fuzzer")
    for data in frames:
        ctrl.send(CanFrame(LSS_MASTER_COB_ID, data))
        clock.advance(0.002)
    clock.advance(0.5)
    valid = {0x44, 0x11, 0x13, 0x17, 0x4F, 0x50, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E}
    for f in answers:
        assert len(f.data) == 8 and f.data[0] in valid
    assert d.node.running
