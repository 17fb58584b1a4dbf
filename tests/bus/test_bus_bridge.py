"""``[[bridge]]``: a rig bus joined to a python-can bus (issue 24, 'Bridges to any python-can bus'):
frames both ways, no echo loops, timestamps kept, canopen on the far side reading and moving a drive,
the real side's failures (an adapter that vanishes and comes back, bus-off) retried with back-off
while the rig runs on, one line for an interface that does not exist; python-can's ``virtual`` and
``udp_multicast`` (in a network namespace with only ``lo``) as the real side."""

from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import bridge_kit
import can
import canopen
import pytest
from csp_loop_kit import csp_loop

from gatewaylab.bus import CanFrame
from gatewaylab.bus.bridge import Backoff, EchoFilter, LinkState, Verdict, classify
from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.bridge import PythonCanBridge
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

HERE = Path(__file__).resolve().parent
DRIVE = {"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"}


class Seen:
    """Frames on the rig's bus, with an event per CAN id a test waits on."""

    def __init__(self) -> None:
        self.frames: list[tuple[CanFrame, float]] = []
        self.events: dict[int, threading.Event] = {}

    def __call__(self, frame: CanFrame, t: float) -> None:
        self.frames.append((frame, t))
        self.event(frame.can_id).set()

    def event(self, can_id: int) -> threading.Event:
        return self.events.setdefault(can_id, threading.Event())

    def ids(self, can_id: int) -> list[CanFrame]:
        return [f for f, _ in self.frames if f.can_id == can_id]


def start_rig(bridge: dict[str, Any], drive: bool = False) -> tuple[Rig, threading.Thread, Seen]:
    config = parse_rig({"clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}],
                        "drive": [DRIVE] if drive else [], "bridge": [bridge]})
    rig = Rig(config)
    rig.buses["can0"].attach("acker")     # acknowledges what the bridge puts on an otherwise empty bus
    seen = Seen()
    rig.buses["can0"].add_monitor(seen)
    return rig, rig.run_in_thread(), seen


@pytest.fixture
def rigs() -> Iterator[list[tuple[Rig, threading.Thread]]]:
    started: list[tuple[Rig, threading.Thread]] = []
    yield started
    for rig, thread in started:
        rig.request_stop()
        thread.join(10)
        rig.close()


def bridge_of(rig: Rig) -> PythonCanBridge:
    [bridge] = [p for p in rig.participants if isinstance(p, PythonCanBridge)]
    return bridge


def wait_state(bridge: PythonCanBridge, state: LinkState, started: threading.Thread) -> None:
    """The bridge is started by the rig thread: wait until it has opened (or failed)."""
    assert bridge.wait_for(state, 10), f"bridge {bridge.state}, not {state}"
    assert started.is_alive()


def test_verdicts_backoff_and_echo_filter() -> None:
    """linux/can/error.h: an error frame with CAN_ERR_BUSOFF (0x40) means bus-off; own frames come back
    with is_rx false; the back-off doubles up to its maximum and starts over once the link works."""
    assert classify(False, True, 0x123) is Verdict.FORWARD
    assert classify(False, False, 0x123) is Verdict.ECHO
    assert classify(True, True, 0x040) is Verdict.BUS_OFF
    assert classify(True, True, 0x088) is Verdict.ERROR
    b = Backoff(0.1, 0.5)
    assert [b.next() for _ in range(5)] == [0.1, 0.2, 0.4, 0.5, 0.5]
    b.reset()
    assert b.next() == 0.1
    f = EchoFilter(window=0.5)
    f.sent(CanFrame(0x80), 10.0)
    f.sent(CanFrame(0x80), 10.1)
    assert f.is_echo(CanFrame(0x80), 10.2) and not f.is_echo(CanFrame(0x81), 10.2)
    assert not f.is_echo(CanFrame(0x80), 10.7)      # the second one's window is over


def test_frames_both_ways_with_timestamps_and_no_echo(rigs: list) -> None:
    """Virtual -> real: the frame arrives once with its virtual-bus time as Unix time (python-can
    virtual with preserve_timestamps keeps it); real -> virtual: a far node's frame is on the rig bus;
    with receive_own_messages the bridge's own frames come back (is_rx false) and are dropped."""
    rig, thread, seen = start_rig({"bus": "can0", "interface": "virtual", "channel": "both-ways",
                                   "receive_own_messages": True, "options": {"preserve_timestamps": True}})
    rigs.append((rig, thread))
    bridge = bridge_of(rig)
    wait_state(bridge, LinkState.UP, thread)
    far = can.Bus(interface="virtual", channel="both-ways")
    try:
        source = rig.buses["can0"].attach("source")
        rig.clock.call_soon_threadsafe(source.send, CanFrame(0x321, b"\x01\x02"))
        msg = far.recv(10)
        assert msg is not None and msg.arbitration_id == 0x321 and bytes(msg.data) == b"\x01\x02"
        [t] = [t for f, t in seen.frames if f.can_id == 0x321]
        assert msg.timestamp == pytest.approx(rig.clock.wall_epoch + t, abs=1e-6)
        far.send(can.Message(arbitration_id=0x7FE, data=b"\xaa", is_extended_id=False))
        assert seen.event(0x7FE).wait(10)
        # the echo of 0x321 was queued before 0x7FE: it has been seen and dropped by now
        assert len(seen.ids(0x321)) == 1 and bridge.stats.echoes == 1
        far.send(can.Message(arbitration_id=0x1BCDEF00, data=bytes(8), is_extended_id=True))
        assert seen.event(0x1BCDEF00).wait(10)
        assert seen.ids(0x1BCDEF00)[0].extended and bridge.stats.from_real == 2
        assert far.recv(0.2) is None                      # nothing else came back to the far side
    finally:
        far.shutdown()


def test_canopen_on_the_far_side_reads_and_moves_a_drive(rigs: list) -> None:
    """CiA 301 SDO (0x1008, segmented), CiA 402 profile position (0x6060 = 1, 0x607A, controlword
    0x1F then 0x0F, statusword bit 10 target reached) and a CSP loop of SYNC/RPDO1/TPDO1 from a
    canopen master behind the bridge."""
    logging.getLogger("canopen").setLevel(logging.ERROR)
    rig, thread, _ = start_rig({"bus": "can0", "interface": "virtual", "channel": "far-master"}, drive=True)
    rigs.append((rig, thread))
    wait_state(bridge_of(rig), LinkState.UP, thread)
    network = canopen.Network(can.Bus(interface="virtual", channel="far-master"))
    network.connect()
    try:
        node = network.add_node(2, rig.ready_info()["canopen"]["can0"]["axis2"]["eds"])
        assert "gatewaylab" in node.sdo[0x1008].raw
        node.sdo[0x6060].raw = 1
        for cw in (0x06, 0x07, 0x0F):
            node.sdo[0x6040].raw = cw
        node.sdo[0x607A].raw = 3000
        node.sdo[0x6040].raw = 0x1F
        node.sdo[0x6040].raw = 0x0F
        for _ in range(5000):                             # paced by the SDO round trips
            if node.sdo[0x6041].raw & 0x400:
                break
        assert node.sdo[0x6041].raw & 0x400
        assert abs(node.sdo[0x6064].raw - 3000) <= node.sdo[0x6067].raw
        received, _, _ = csp_loop(network, node, 100)     # and PDOs: SYNC + RPDO1 out, TPDO1 back
        assert received >= 95
    finally:
        network.disconnect()


def test_an_adapter_that_vanishes_and_comes_back(rigs: list, caplog: pytest.LogCaptureFixture) -> None:
    """The adapter is unplugged: one warning line, the bridge is down and retries with back-off while
    the rig runs on (its frames count as lost); plugged in again, frames cross again."""
    adapter = bridge_kit.register("flaky-usb")
    rig, thread, seen = start_rig({"bus": "can0", "interface": bridge_kit.INTERFACE, "channel": "flaky-usb",
                                   "retry_initial": 0.02, "retry_max": 0.1})
    rigs.append((rig, thread))
    bridge = bridge_of(rig)
    wait_state(bridge, LinkState.UP, thread)
    far = can.Bus(interface="virtual", channel="flaky-usb")
    try:
        far.send(can.Message(arbitration_id=0x101, data=b"\x01", is_extended_id=False))
        assert seen.event(0x101).wait(10)
        with caplog.at_level(logging.DEBUG, logger="gatewaylab.rig.bridge"):
            adapter.plugged = False
            assert adapter.failed.wait(10)
            adapter.failed.clear()
            assert adapter.failed.wait(10)                 # a reopen attempt failed too: still down
            assert bridge.state is LinkState.DOWN
            lost = bridge.lost
            source = rig.buses["can0"].attach("source")
            for can_id in (0x202, 0x203):
                rig.clock.call_soon_threadsafe(source.send, CanFrame(can_id))
            # 0x203 ended after 0x202 had been handed to every controller (the rig thread, in order)
            assert seen.event(0x203).wait(10)
            assert bridge.lost == lost + 2 and thread.is_alive()
            adapter.opened.clear()
            adapter.plugged = True
            assert adapter.opened.wait(10)
            wait_state(bridge, LinkState.UP, thread)
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len([w for w in warnings if "down" in w]) == 1, warnings
        assert any("up again" in w for w in warnings)
        assert bridge.stats.reconnects == 1 and adapter.opens == 2
        far.send(can.Message(arbitration_id=0x103, data=b"\x03", is_extended_id=False))
        assert seen.event(0x103).wait(10)
    finally:
        far.shutdown()


def test_an_adapter_missing_at_start_is_one_line_and_the_rig_runs(rigs: list,
                                                                  caplog: pytest.LogCaptureFixture) -> None:
    """No adapter when the rig starts: one warning line naming the bridge and the adapter, the rig runs
    (state down); the adapter plugged in later is opened by the next attempt."""
    adapter = bridge_kit.register("late-usb")
    adapter.plugged = False
    with caplog.at_level(logging.WARNING, logger="gatewaylab.rig.bridge"):
        rig, thread, seen = start_rig({"bus": "can0", "interface": bridge_kit.INTERFACE, "channel": "late-usb",
                                       "retry_initial": 0.02, "retry_max": 0.1})
        rigs.append((rig, thread))
        bridge = bridge_of(rig)
        wait_state(bridge, LinkState.DOWN, thread)
        adapter.plugged = True
        wait_state(bridge, LinkState.UP, thread)
    [line] = [r.getMessage() for r in caplog.records if "down" in r.getMessage()]
    assert "bridge-can0-gatewaylab_flaky" in line and "late-usb" in line and "unplugged" in line
    far = can.Bus(interface="virtual", channel="late-usb")
    try:
        far.send(can.Message(arbitration_id=0x104, data=b"\x04", is_extended_id=False))
        assert seen.event(0x104).wait(10)
    finally:
        far.shutdown()


def test_bus_off_of_the_real_side_restarts_the_link(rigs: list, caplog: pytest.LogCaptureFixture) -> None:
    """An error frame with CAN_ERR_BUSOFF from the real side: reported (state bus-off, one warning),
    the adapter reopened after the back-off; nothing of it reaches the virtual bus."""
    adapter = bridge_kit.register("busoff-usb")
    rig, thread, seen = start_rig({"bus": "can0", "interface": bridge_kit.INTERFACE, "channel": "busoff-usb",
                                   "retry_initial": 0.02})
    rigs.append((rig, thread))
    bridge = bridge_of(rig)
    wait_state(bridge, LinkState.UP, thread)
    far = can.Bus(interface="virtual", channel="busoff-usb")
    try:
        adapter.opened.clear()
        with caplog.at_level(logging.WARNING, logger="gatewaylab.rig.bridge"):
            far.send(can.Message(arbitration_id=0x040, is_error_frame=True, data=bytes(8)))
            assert adapter.opened.wait(10)
            wait_state(bridge, LinkState.UP, thread)
        assert any("bus-off" in r.getMessage() for r in caplog.records)
        assert bridge.stats.error_frames == 1 and bridge.stats.reconnects == 1 and not seen.frames
    finally:
        far.shutdown()


def test_an_interface_python_can_lacks_is_one_line_at_start(tmp_path: Path) -> None:
    """A missing driver stops the rig at start with one line naming the bridge (exit 2 from the CLI)."""
    config = parse_rig({"clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}],
                        "bridge": [{"bus": "can0", "interface": "no_such_adapter", "channel": "x"}]})
    with Rig(config) as rig, pytest.raises(ConfigError) as info:
        rig.start()
    assert "bridge-can0-no_such_adapter" in str(info.value) and "\n" not in str(info.value)
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text('clock = "realtime"\n[[bus]]\nname = "can0"\n[[bridge]]\nbus = "can0"\n'
                        'interface = "no_such_adapter"\n')
    run = subprocess.run([sys.executable, "-m", "gatewaylab", "run", str(rig_file)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.strip().count("\n") == 0 and "no_such_adapter" in run.stderr


def test_bridge_keys_are_checked() -> None:
    """One ConfigError line per bad key (the shared rig-file validator)."""
    base = {"clock": "realtime", "bus": [{"name": "can0"}]}
    with pytest.raises(ConfigError, match=r"\[\[bridge\]\] #1.*names an unknown bus"):
        parse_rig({**base, "bridge": [{"bus": "can9", "interface": "virtual"}]})
    with pytest.raises(ConfigError, match=r"interface is required"):
        parse_rig({**base, "bridge": [{"bus": "can0"}]})
    with pytest.raises(ConfigError, match=r"unknown keys \['bitrat'\]"):
        parse_rig({**base, "bridge": [{"bus": "can0", "interface": "virtual", "bitrat": 5}]})
    config = parse_rig({**base, "bridge": [{"bus": "can0", "interface": "virtual", "channel": 1.5}]})
    with pytest.raises(ConfigError, match="channel must be a string or an integer"):
        Rig(config, endpoints=False)


def _netns_unavailable() -> str | None:
    if not sys.platform.startswith("linux") or shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs Linux with unshare and ip (iproute2)"
    if os.geteuid() != 0:
        return "needs root to make a network namespace (unshare -n) that keeps udp_multicast on loopback"
    if importlib.util.find_spec("msgpack") is None:
        return "python-can's udp_multicast needs msgpack (pip install msgpack)"
    return None


@pytest.mark.net
@pytest.mark.skipif(_netns_unavailable() is not None, reason=str(_netns_unavailable()))
def test_udp_multicast_as_the_real_side_in_a_loopback_only_namespace() -> None:
    """python-can's udp_multicast binds to every interface and joins its group on the default one, so it
    runs in a network namespace with only lo (hop limit 0): `gatewaylab run` bridges can0 to it and a
    canopen master on the far side reads 0x1008 and moves the drive (tests/bus/bridge_netns_driver.py)."""
    run = subprocess.run(["unshare", "-n", sys.executable, str(HERE / "bridge_netns_driver.py")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.startswith("OK IDX")
