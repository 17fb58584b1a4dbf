"""Drives of a running rig through the python ``canopen`` package, as its users write it (issue 21, "The user's
path as a suite"; docs/canopen-drive.md): ``Network.connect(interface="gatewaylab", channel=...)`` with the
endpoint and the drives' EDS files from the ready file, SDO upload of 0x1008, NMT start, a TPDO loop with
canopen's PDO callbacks (TPDO configured by SDO: ``tpdo.read()`` / ``save()``), and a CiA 402 enable +
profile position move with ``BaseNode402`` over its PDOs. Latency: the first answer / PDO after connect or
start (< 1 s) and the steady state (p99 of SDO round trips, of TPDO bus time -> callback).
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable, Iterator

import canopen
import pytest
from userpath_kit import RIG_TWO_DRIVES, Latencies, bound, measured, wait_until

from gatewaylab.rig.process import RigProcess

RIG = RIG_TWO_DRIVES

DEADLINE = 20.0
# BaseNode402 warns for every object it reaches by SDO instead of PDO (the drive's defaults map some only)
logging.getLogger("canopen.profiles.p402").setLevel(logging.ERROR)


@pytest.fixture(scope="module")
def rig(start_rig: Callable[..., RigProcess]) -> RigProcess:
    return start_rig(RIG)


def eds(rig: RigProcess, node_id: int) -> str:
    """The EDS the rig wrote for a drive (ready file ``canopen``)."""
    drives = rig.info["canopen"]["can0"]
    return next(str(d["eds"]) for d in drives.values() if d["node_id"] == node_id)


@pytest.fixture
def network(rig: RigProcess) -> Iterator[canopen.Network]:
    net = canopen.Network()
    net.connect(interface="gatewaylab", channel=rig.info["buses"]["can0"]["endpoint"])
    try:
        yield net
    finally:
        net.disconnect()


@measured
def test_sdo_upload_of_the_device_name_first_and_steady(rig: RigProcess) -> None:
    """CiA 301 7.2.4 SDO upload (segmented for 0x1008 'manufacturer device name'): the name of both drives;
    the first answer after connecting within a second, then SDO round trips of 0x6041 (expedited); the
    connect itself within a few seconds (the first one in a process imports the interface)."""
    started = time.time()
    net = canopen.Network()
    net.connect(interface="gatewaylab", channel=rig.info["buses"]["can0"]["endpoint"])
    connected = time.time()
    print(f"\ncanopen Network.connect: {(connected - started) * 1e3:.1f} ms (the first includes imports)")
    bound(connected - started, 5.0, "canopen Network.connect")
    try:
        node2 = net.add_node(2, eds(rig, 2))   # parses the EDS (client side)
        asked = time.time()
        assert node2.sdo.upload(0x1008, 0).decode() == "IDX 56 M CANopen (gatewaylab)"
        lat = Latencies("canopen SDO upload round trip")
        lat.first = time.time() - asked
        node3 = net.add_node(3, eds(rig, 3))
        assert node3.sdo[0x1008].raw == "IDX 56 M CANopen (gatewaylab)"
        assert node3.sdo[0x1018][4].raw == 0x1003
        for _ in range(200):
            t = time.time()
            node2.sdo.upload(0x6041, 0)
            lat.add(time.time() - t)
    finally:
        net.disconnect()
    lat.check()


@measured
def test_nmt_start_then_tpdo_callbacks(rig: RigProcess, network: canopen.Network) -> None:
    """CiA 301 7.2.2 PDO + 7.2.8 NMT: TPDO1 (statusword + position actual value, the drive's default
    mapping) configured by SDO with an event timer of 5 ms (0x1800:05), then NMT start: canopen's PDO
    callback fires every cycle with the statusword's 'remote' bit set (IDX guide table 3-11 note 3); NMT
    pre-operational ends the loop. Latency: NMT start -> first callback, TPDO bus time -> callback."""
    node = network.add_node(2, eds(rig, 2))
    node.nmt.state = "PRE-OPERATIONAL"
    node.tpdo.read()
    tpdo = node.tpdo[1]
    assert [v.index for v in tpdo] == [0x6041, 0x6064]
    tpdo.trans_type = 255
    tpdo.event_timer = 5
    tpdo.enabled = True
    node.tpdo.save()
    lock = threading.Lock()
    calls: list[tuple[float, float, int]] = []     # (bus time, callback wall time, statusword)

    def on_tpdo(pdo: canopen.pdo.PdoMap) -> None:
        with lock:
            calls.append((float(pdo.timestamp or 0.0), time.time(), int(pdo["Statusword"].raw)))

    tpdo.add_callback(on_tpdo)
    started = time.time()
    node.nmt.state = "OPERATIONAL"
    wait_until(lambda: len(calls) >= 200, DEADLINE, "200 TPDO1 callbacks")
    node.nmt.state = "PRE-OPERATIONAL"
    with lock:
        seen = list(calls)
    lat = Latencies("canopen TPDO1 (event timer 5 ms): bus -> callback")
    lat.first = seen[0][1] - started
    for bus_time, wall, _ in seen[1:]:
        lat.add(wall - bus_time)
    assert all(sw & 0x200 for _, _, sw in seen), "statusword bit 9 'remote' while Operational"
    periods = sorted(b - a for (a, _, _), (b, _, _) in itertools.pairwise(seen))
    assert 0.002 < periods[len(periods) // 2] < 0.05, periods    # event timer 5 ms (generous)
    lat.check()


@measured
def test_cia402_enable_and_profile_position_move(rig: RigProcess, network: canopen.Network) -> None:
    """CiA 402 V4.0 through canopen's BaseNode402 with the drive's default PDOs (docs/canopen-drive.md:
    RPDO1 controlword + target position, RPDO4 mode, TPDO1 statusword + position): switch on disabled ->
    operation enabled, profile position (mode 1), a new set point (bit 4, acknowledged by statusword bit
    12), 'target reached' (bit 10) with the position inside the window 0x6067. Latency: enabling within a
    second; TPDO1 bus time -> callback while the axis moves."""
    node = canopen.BaseNode402(3, eds(rig, 3))
    network.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    node.setup_402_state_machine()
    assert 0x6040 in node.rpdo_pointers and 0x607A in node.rpdo_pointers and 0x6041 in node.tpdo_pointers
    node.tpdo[1].add_callback(lambda pdo: lat.add(time.time() - float(pdo.timestamp or 0.0)))
    lat = Latencies("CiA 402 move: TPDO1 bus -> callback")
    node.nmt.state = "OPERATIONAL"
    started = time.time()
    node.state = "OPERATION ENABLED"
    lat.first = time.time() - started
    node.op_mode = "PROFILED POSITION"
    assert node.sdo[0x6061].raw == 1
    target = node.sdo[0x6064].raw + 4000                      # a second run moves on from there
    window = node.sdo[0x6067].raw
    node.rpdo_pointers[0x607A].raw = target
    node.controlword = 0x1F                                     # new set point, absolute, via RPDO1
    wait_until(lambda: node.statusword & 0x1000, DEADLINE, "set-point acknowledge (bit 12)")
    node.controlword = 0x0F
    wait_until(lambda: node.statusword & 0x400 and abs(node.tpdo_values[0x6064] - target) <= window,
               DEADLINE, "target reached (bit 10) at the target")
    assert abs(node.sdo[0x6064].raw - target) <= window
    assert node.state == "OPERATION ENABLED"
    node.state = "SWITCH ON DISABLED"
    node.nmt.state = "PRE-OPERATIONAL"
    lat.check()
