"""A recorded CANopen session for the monitor tests: every frame type the monitor decodes, produced by
the project's own nodes and masters on a simulated clock (so the trace is the same on every run)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from canopen_testkit import sample_od

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.lss import LssMaster, LssState
from gatewaylab.canopen.node import Node
from gatewaylab.canopen.sdo_client import SdoClient
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive

UNCONFIGURED_SERIAL = 0x00C0FFEE


@dataclass
class Session:
    frames: list[tuple[CanFrame, float]]
    drives: dict[int, Drive]
    results: dict[str, Any] = field(default_factory=dict)


def record_session() -> Session:
    """Two configured drives (2, 3) and an unconfigured one; a master that reads and writes by SDO
    (two nodes interleaved, segmented, block and expedited, one abort), starts the nodes, sends SYNC and
    TIME, enables drive 2 through SDO, makes drive 3 fault (EMCY) and finds the new drive by Fastscan."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=1_000_000)
    frames: list[tuple[CanFrame, float]] = []
    bus.add_monitor(lambda f, t: frames.append((f, t)))
    drives = {2: Drive(clock, bus, 2, 0x1002, name="axis2"), 3: Drive(clock, bus, 3, 0x1003, name="axis3")}
    new = Drive(clock, bus, None, UNCONFIGURED_SERIAL, name="new")
    plain = Node(clock, bus, 5, sample_od(), name="node5")
    master = bus.attach("master")
    sdo = SdoClient(clock, master.send)
    lss = LssMaster(clock, master.send)

    def on_frame(frame: CanFrame, t: float) -> None:
        sdo.on_frame(frame, t)
        lss.on_frame(frame, t)

    master.on_frame = on_frame
    results: dict[str, Any] = {}
    with clock.lock:
        for d in (*drives.values(), new, plain):
            d.start()
        clock.advance(0.05)
        # segmented and block downloads to node 5
        sdo.download(5, 0x2001, 0, b"hello monitor", lambda r: results.__setitem__("seg_down", r))
        sdo.download(5, 0x2002, 0, bytes(range(100)), lambda r: results.__setitem__("block_down", r), block=True)
        # remap drive 3's TPDO1 to statusword + velocity actual value (CiA 301 7.5.2.36 procedure)
        for index, sub, value, size in ((0x1800, 1, 0x80000183, 4), (0x1A00, 0, 0, 1), (0x1A00, 1, 0x60410010, 4),
                                        (0x1A00, 2, 0x606C0020, 4), (0x1A00, 0, 2, 1), (0x1800, 1, 0x183, 4)):
            sdo.download(3, index, sub, value.to_bytes(size, "little"), lambda r: results.setdefault("remap", r))
        clock.advance(0.05)
        # two uploads of two nodes in flight at once: their frames interleave on the bus
        sdo.upload(2, 0x1008, 0, lambda r: results.__setitem__("name2", r))
        sdo.upload(3, 0x1018, 4, lambda r: results.__setitem__("serial3", r))
        sdo.upload(3, 0x1008, 0, lambda r: results.__setitem__("name3_block", r), block=True)
        clock.advance(0.05)
        sdo.upload(2, 0x1234, 0, lambda r: results.__setitem__("abort", r))
        sdo.download(2, 0x1017, 0, (100).to_bytes(2, "little"), lambda r: results.__setitem__("hb", r))
        sdo.download(3, 0x1017, 0, (100).to_bytes(2, "little"), lambda r: None)
        clock.advance(0.05)
        master.send(CanFrame(0x000, bytes((0x01, 0))))          # NMT start all
        clock.advance(0.25)                                      # heartbeats
        for cw in (0x06, 0x07, 0x0F):                            # enable drive 2 by SDO
            sdo.download(2, 0x6040, 0, cw.to_bytes(2, "little"), lambda r: None)
            clock.advance(0.01)
        for _ in range(3):
            master.send(CanFrame(0x080, b""))                     # SYNC -> TPDOs
            clock.advance(0.01)
        master.send(CanFrame(0x100, bytes((0x10, 0x27, 0, 0, 0x64, 0x00))))   # TIME: 10 s, day 100
        clock.advance(0.01)
        drives[3].fault(0x8611, 0x20)                            # following error: EMCY
        clock.advance(0.05)
        master.send(CanFrame(0x000, bytes((0x02, 0))))          # NMT stop all (LSS needs Stopped)
        clock.advance(0.01)
        lss.fast_scan(lambda r: results.__setitem__("fastscan", r))
        clock.run_while(lambda: lss.busy)
        lss.switch_state_global(LssState.WAITING)
        clock.advance(0.05)
    return Session(frames, drives, results)
