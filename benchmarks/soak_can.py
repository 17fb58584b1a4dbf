"""The CAN side of ``make soak-ethercat`` and bench_ethercat_tail: python-can clients on the rig's buses, in a
child process of their own (the master's cycle and the rig are other processes), counting what they sent,
what the buses refused and what they heard."""

from __future__ import annotations

import multiprocessing as mp
import struct
import time
from multiprocessing.synchronize import Event
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from benchmarks.soak_ethercat import Plan

__all__ = ["CAN_NODE", "DRAIN_S", "SYNC_ID", "CanLoad", "can_peer"]

#: the ids of the CAN traffic: the drive's RPDO1 (node 2) and the SYNC the master sends through the ECAN-Lite
CAN_NODE = 2
SYNC_ID = 0x080
#: how long the CAN client keeps listening after the run (frames still on their way to it)
DRAIN_S = 0.5


def can_peer(endpoints: list[str], plan: Plan, stop: Event, results: Any) -> None:
    """The python-can client(s) on the rig's buses: on ``can0`` NMT start + RPDO1 to the CAN drive at
    ``plan.can_rate``; on every ECAN-Lite bus ``plan.peer_rate`` frames/s towards the master. Counts what it
    sent, what the bus refused (a full transmit queue), what it heard from the master (the ECAN-Lite's
    frames: SYNC and ids 0x100..) and other frames (the CAN drive's)."""
    import can

    buses = [can.Bus(interface="gatewaylab", channel=e, name=f"soak-peer-{k}") for k, e in enumerate(endpoints)]
    counts = {"sent": 0, "refused": 0, "heard": 0, "other": 0}

    def send(bus: Any, msg: Any) -> None:
        try:
            bus.send(msg, timeout=0)
            counts["sent"] += 1
        except can.CanOperationError:
            counts["refused"] += 1
    def take() -> None:
        for bus in buses:
            while (msg := bus.recv(0)) is not None:
                master_frame = msg.arbitration_id == SYNC_ID or 0x100 <= msg.arbitration_id < 0x100 + len(buses)
                counts["heard" if master_frame else "other"] += 1
    results.put({"ready": True})
    try:
        if plan.can_drive:
            send(buses[0], can.Message(arbitration_id=0x000, is_extended_id=False, data=[0x01, CAN_NODE]))
        t0 = time.perf_counter()
        rpdo = peer = 0
        while not stop.is_set():
            now = time.perf_counter() - t0
            while plan.can_drive and rpdo < now * plan.can_rate:
                send(buses[0], can.Message(arbitration_id=0x200 + CAN_NODE, is_extended_id=False,
                                           data=struct.pack("<Hi", 0x0F, rpdo)))
                rpdo += 1
            while plan.peer_rate and peer < now * plan.peer_rate:
                for k, bus in enumerate(buses):
                    send(bus, can.Message(arbitration_id=0x300 + k, is_extended_id=False, data=struct.pack("<I", peer)))
                peer += 1
            take()
            time.sleep(0.0005)
        drain_end = time.monotonic() + DRAIN_S      # what the master's last cycles put on the buses
        while time.monotonic() < drain_end:
            take()
            time.sleep(0.001)
    finally:
        results.put(counts)
        for bus in buses:
            bus.shutdown()


class CanLoad:
    """:func:`can_peer` in a child process for the plan's buses, returned once its buses are open (nothing
    when the plan has no CAN side)."""

    def __init__(self, plan: Plan, endpoints: list[str]) -> None:
        ctx = mp.get_context("spawn")
        self.stop_event = ctx.Event()
        self.results: Any = ctx.Queue()
        self.proc: Any = None
        if endpoints and (plan.can_drive or plan.peer_rate):
            self.proc = ctx.Process(target=can_peer, args=(endpoints, plan, self.stop_event, self.results),
                                    name="soak-ethercat-can")
            self.proc.start()
            self.results.get(timeout=120)

    def stop(self) -> dict[str, int]:
        """End the client; its counts ({} without one)."""
        if self.proc is None:
            return {}
        self.stop_event.set()
        try:
            result: dict[str, int] = self.results.get(timeout=30)
        except Exception as exc:
            result = {}
            print(f"the CAN client gave no counts ({type(exc).__name__}, exit {self.proc.exitcode})", flush=True)
        self.proc.join(10)
        if self.proc.is_alive():
            self.proc.kill()
        return result
