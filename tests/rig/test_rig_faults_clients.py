"""Each fault as a real client sees it (issue 14 'Break', 'Done means': each fault seen by a real client).

A `gatewaylab run` rig in its own process (the default rig: IDX idx1 node 1, drives axis2 / axis3),
faults sent from this process through the control endpoint (`gatewaylab fault`'s own code, and the
command itself for some), and clients we did not write watching: python-canopen (EMCY consumer,
heartbeat / boot-up), python-can on the `gatewaylab` interface (error frames, aborted frames),
pyserial under the IDX host client (USB disconnect). Every wait has a generous timeout; nothing
asserts timing.
"""

from __future__ import annotations

import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
import serial
from canopen.nmt import NmtError

from gatewaylab.cli.fault import send_request
from gatewaylab.hosts.maxon_idx.client import IdxClient
from gatewaylab.rig.process import RigProcess

WAIT = 20.0


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[RigProcess]:
    with RigProcess(None, workdir=tmp_path) as r:
        yield r


def _fault(rig: RigProcess, **req: Any) -> dict[str, Any]:
    answer = send_request(str(rig.ready_file), req)
    assert answer["ok"], answer
    return answer


def _cli_fault(rig: RigProcess, *args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "gatewaylab", "fault", str(rig.ready_file), *args],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture
def network(rig: RigProcess) -> Iterator[canopen.Network]:
    net = canopen.Network()
    net.connect(interface="gatewaylab", channel=rig.endpoint("can0"))
    try:
        yield net
    finally:
        net.disconnect()


def _heartbeat(node: canopen.RemoteNode, ms: int) -> None:
    node.sdo.download(0x1017, 0, struct.pack("<H", ms))
    node.nmt.wait_for_heartbeat(WAIT)


def _heartbeats_stop(node: canopen.RemoteNode) -> None:
    """The canopen client's heartbeat wait times out (one heartbeat may still be on its way)."""
    with pytest.raises(NmtError):
        node.nmt.wait_for_heartbeat(1.0)
        node.nmt.wait_for_heartbeat(1.0)


def _statusword(node: canopen.RemoteNode) -> int:
    value: int = struct.unpack("<H", node.sdo.upload(0x6041, 0))[0]
    return value


def _wait_fault_state(node: canopen.RemoteNode) -> int:
    """CiA 402 statusword 'Fault' (xxxx xxxx x0xx 1000) after the fault reaction."""
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        sw = _statusword(node)
        if sw & 0x4F == 0x08:
            return sw
    raise AssertionError(f"drive never reached Fault: statusword 0x{sw:04X}")


def _emcy(node: canopen.RemoteNode, code: int) -> Any:
    """The EMCY with ``code`` from python-canopen's consumer (its log, or the next one to come)."""
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        for emcy in node.emcy.log:
            if emcy.code == code:
                return emcy
        node.emcy.wait(code, timeout=1.0)
    raise AssertionError(f"no EMCY 0x{code:04X} from node {node.id}: {node.emcy.log}")


def test_drive_faults_in_canopens_emcy_consumer(rig: RigProcess, network: canopen.Network) -> None:
    """CiA 402 / CiA 301 EMCY: a following error sends EMCY 0x8611 (error register: generic +
    device profile), an over-current EMCY 0x2310 (generic + current); the drive ends in Fault.
    python-canopen's EMCY consumer gets them (node.emcy.wait, node.emcy.active)."""
    axis2 = network.add_node(2, canopen.ObjectDictionary())
    axis3 = network.add_node(3, canopen.ObjectDictionary())
    _fault(rig, fault="drive-fault", device="axis2", kind="following-error")
    emcy = _emcy(axis2, 0x8611)
    assert emcy.register & 0x21 == 0x21
    assert [e.code for e in axis2.emcy.active] == [0x8611]
    _wait_fault_state(axis2)
    assert struct.unpack("<H", axis2.sdo.upload(0x603F, 0))[0] == 0x8611
    out = _cli_fault(rig, "drive-fault", "3", "--bus", "can0", "over-current")
    assert "error_code=0x2310" in out
    emcy = _emcy(axis3, 0x2310)      # it may have come while the command was still printing
    assert emcy.register & 0x03 == 0x03
    _wait_fault_state(axis3)


def test_power_cycle_seen_by_canopen(rig: RigProcess, network: canopen.Network) -> None:
    """CiA 301: switched off, the node's heartbeat stops (the consumer times out); switched on, it
    sends its boot-up message and its dictionary is at power-on values, except what 0x1010 stored."""
    node = network.add_node(2, canopen.ObjectDictionary())
    node.sdo.download(0x30B0, 0, struct.pack("<i", 77))
    node.sdo.download(0x1010, 1, b"save")               # stored: survives
    node.sdo.download(0x6065, 0, struct.pack("<I", 1234))  # volatile: lost
    _heartbeat(node, 50)
    booted = threading.Event()
    node.nmt.add_heartbeat_callback(lambda state: booted.set() if state == 0 else None)
    _fault(rig, fault="power-cycle", device="axis2", off=6.0)
    _heartbeats_stop(node)
    assert booted.wait(WAIT)
    assert struct.unpack("<I", node.sdo.upload(0x6065, 0))[0] == 2000
    assert struct.unpack("<i", node.sdo.upload(0x30B0, 0))[0] == 77


def test_can_unplug_is_a_heartbeat_timeout(rig: RigProcess, network: canopen.Network) -> None:
    """A drive whose CAN connector is pulled falls silent (heartbeat consumer times out) and is
    heard again once replugged (CiA 301 heartbeat protocol)."""
    node = network.add_node(3, canopen.ObjectDictionary())
    _heartbeat(node, 50)
    _cli_fault(rig, "can-unplug", "axis3")
    _heartbeats_stop(node)
    _fault(rig, fault="can-replug", device="axis3")
    node.nmt.wait_for_heartbeat(WAIT)


def _recv_until(bus: can.BusABC, want: Any) -> list[can.Message]:
    seen: list[can.Message] = []
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        msg = bus.recv(0.5)
        if msg is not None:
            seen.append(msg)
            if want(msg):
                return seen
    raise AssertionError(f"not seen within {WAIT} s: {seen[-5:]}")


def test_stuck_dominant_seen_by_canopen_and_python_can(rig: RigProcess, network: canopen.Network) -> None:
    """ISO 11898-1 / CAN 2.0 §8 rule 6: a bus held dominant completes no frame; heartbeats stop (the
    canopen consumer times out), a python-can client receives error frames and its controller goes
    error-passive; after the release the drive, bus-off meanwhile, recovers and beats again."""
    node = network.add_node(2, canopen.ObjectDictionary())
    _heartbeat(node, 20)
    with can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as watcher:
        _fault(rig, fault="stuck-dominant", bus="can0", duration=5.0)
        _heartbeats_stop(node)
        _recv_until(watcher, lambda m: m.is_error_frame)
        _recv_until(watcher, lambda m: watcher.controller_state.name == "ERROR_PASSIVE")
        node.nmt.wait_for_heartbeat(WAIT)                       # released: back
        _recv_until(watcher, lambda m: m.arbitration_id == 0x702 and not m.is_error_frame)


def test_bus_errors_and_bus_off_in_a_python_can_client(rig: RigProcess) -> None:
    """CAN 2.0 §8 rules 3 and 10: with every frame destroyed a python-can sender gets error frames
    (is_error_frame), goes bus-off after 32 of them and its frame is given up; after the span its
    frames pass again (another client receives them)."""
    ep = rig.endpoint("can0")
    with can.Bus(interface="gatewaylab", channel=ep) as sender, \
            can.Bus(interface="gatewaylab", channel=ep, can_filters=[{"can_id": 0x123, "can_mask": 0x7FF}]) as rx:
        _fault(rig, fault="bus-errors", bus="can0", duration=6.0)
        sender.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        errors = 0
        deadline = time.monotonic() + WAIT
        while sender.tx_errors == 0 and time.monotonic() < deadline:   # the frame given up at bus-off
            msg = sender.recv(0.5)
            errors += msg is not None and msg.is_error_frame
        while (msg := sender.recv(0.5)) is not None:                    # read before the abort came
            errors += msg.is_error_frame
        assert sender.tx_errors == 1 and errors >= 32                   # 32 x 8 = 256: bus-off
        deadline = time.monotonic() + WAIT
        got = None
        while got is None and time.monotonic() < deadline:
            try:
                sender.send(can.Message(arbitration_id=0x123, data=b"\x02", is_extended_id=False))
            except can.CanOperationError:
                pass                              # bus-off or still inside the span
            msg = rx.recv(1.0)
            while msg is not None and got is None:     # error frames of the span come first
                if not msg.is_error_frame and msg.data == b"\x02":
                    got = msg
                msg = rx.recv(0)
        assert got is not None


def test_drop_and_corrupt_one_id_seen_by_python_can(rig: RigProcess) -> None:
    """docs/faults.md: drop takes the next frame of one id off the bus (the receiver never sees it,
    other ids pass); corrupt makes it a CRC error frame (the receiver sees the error, then the
    retransmission)."""
    ep = rig.endpoint("can0")
    with can.Bus(interface="gatewaylab", channel=ep) as tx, can.Bus(interface="gatewaylab", channel=ep) as rx:
        rx.set_filters([{"can_id": 0x120, "can_mask": 0x7F0}])
        _fault(rig, fault="drop", bus="can0", can_id=0x121, count=1)
        for can_id, data in ((0x121, b"\x01"), (0x122, b"\x02"), (0x121, b"\x03")):
            tx.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        got = [(m.arbitration_id, bytes(m.data)) for m in _recv_until(rx, lambda m: m.data == b"\x03")
               if not m.is_error_frame]
        assert got == [(0x122, b"\x02"), (0x121, b"\x03")]
        _fault(rig, fault="corrupt", bus="can0", can_id=0x122, count=1)
        tx.send(can.Message(arbitration_id=0x122, data=b"\x04", is_extended_id=False))
        seen = _recv_until(rx, lambda m: m.data == b"\x04")
        assert seen[0].is_error_frame and not seen[-1].is_error_frame


def test_idx_usb_disconnect_seen_by_the_idx_client(rig: RigProcess) -> None:
    """IDX guide chapter 2 (USB communication) is silent on a disconnect; as a USB device that
    disappears (docs/decisions.md): pulled, the host's open port fails (pyserial raises, on the pty
    and on TCP), new connections are refused; replugged, the host reads objects again."""
    usb = rig.info["usb"]["idx1"]
    tcp = IdxClient(usb["tcp"])
    pty = IdxClient(usb["pty"])
    try:
        assert tcp.read(0, 0x1018, 4) == 0x2001 and pty.read(0, 0x1018, 4) == 0x2001
        _fault(rig, fault="usb-unplug", device="idx1")
        for client in (tcp, pty):
            with pytest.raises((serial.SerialException, OSError)):
                client.read(0, 0x1018, 4)
        with pytest.raises((serial.SerialException, OSError)):
            IdxClient(usb["tcp"])
    finally:
        tcp.close()
        pty.close()
    answer = _fault(rig, fault="usb-replug", device="idx1")
    with IdxClient(answer["usb"]["idx1"]["tcp"]) as again:
        assert again.read(0, 0x1018, 4) == 0x2001
    with IdxClient(answer["usb"]["idx1"]["pty"]) as again:
        assert again.read(0, 0x1018, 4) == 0x2001
