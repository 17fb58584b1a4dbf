"""CPU time per 1 kHz cycle of an EtherCAT segment, in process (no veth, no root): N CiA 402 drives in CSP
+ 8 ``ethercat_io``, the in-process master's LRW frame (outputs of every slave, then their inputs, as SOEM
maps them).

Two parts are timed (``time.thread_time``, best of ``ROUNDS`` rounds of ``CYCLES`` cycles): the frame
path (``Segment.process``: what the wire thread does between receiving a frame and sending it back) and
the work after the reply (``Segment.after_frame`` and the clock events the cycle scheduled: the drives'
control periods). The sum is what the wire thread spends per cycle; at 1 kHz on one CPU it must stay
well below 1000 us. Printed, never asserted. ``python -m benchmarks.bench_ethercat_cycle [N ...]``;
``--profile N`` prints a cProfile of the pure-Python parts at N drives.
"""

from __future__ import annotations

import struct
import sys
import time
from collections.abc import Callable
from typing import Any

IO_WITH = 8
RX = struct.Struct("<HiihB")
CYCLES = 500
ROUNDS = 5


def build(drives: int, ios: int = IO_WITH) -> tuple[Any, Any, bytearray, Callable[[int], None]]:
    """A segment in OP with ``drives`` enabled drives (CSP) + ``ios`` io; (clock, segment, frame, set_cycle)."""
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.ethercat_drive import EthercatDrive
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    from gatewaylab.ethercat.esc import AlState
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.hosts.ethercat.master import Master

    clock = SimulatedClock()
    devices = [EthercatDrive(clock, f"GL-Drive #{i}", serial=0x3001 + i) for i in range(drives)]
    slaves = [d.slave for d in devices] + [create_io_slave(clock, f"GL-IO #{i}", revision=i + 1)
                                           for i in range(ios)]
    segment = Segment(slaves)
    frames: list[bytes] = []

    def link(raw: bytes) -> bytes | None:
        frames.append(raw)
        buf = bytearray(raw)
        ok = segment.process(buf)     # the applications' work included (no defer)
        return bytes(buf) if ok else None

    m = Master(clock, link=link)
    m.scan()
    m.set_state(AlState.PREOP)
    m.config_map()
    m.set_state(AlState.SAFEOP)
    for _ in range(2):
        m.exchange_process_data()
        clock.advance(0.001)
    m.set_state(AlState.OP)

    def outputs(i: int, cw: int = 0x0F) -> None:
        target = 20 * (i % 2000 if (i // 2000) % 2 == 0 else 2000 - i % 2000)
        for pos in range(drives):
            m.pdo_write(pos, 0, RX.pack(cw, target, 0, 0, 8))
        for pos in range(drives, drives + ios):
            m.pdo_write(pos, 0, bytes([i & 0xFF]) * 5)

    for cw in (0x06, 0x07, 0x0F):
        outputs(0, cw)
        for _ in range(20):
            m.exchange_process_data()
            clock.advance(0.001)
    enabled = sum(1 for d in devices if d.drive.state.name == "OPERATION_ENABLED")
    if enabled != drives:
        raise RuntimeError(f"{enabled}/{drives} drives enabled")
    frames.clear()
    m.exchange_process_data()
    clock.advance(0.001)
    frame = bytearray(frames[-1])

    def set_cycle(i: int) -> None:
        outputs(i)
        frames.clear()
        # the master's image into the frame's LRW data (offset 14 + 2 + 10)
        frame[:] = _frame_of(m)

    def _frame_of(master: Any) -> bytes:
        from gatewaylab.ethercat.datagram import Command, Datagram, Frame, encode_frame
        process = master.process
        (a, n), = process.chunks
        return encode_frame(Frame((Datagram(Command.LRW, 1, a, bytes(process.image[a:a + n])),)))

    return clock, segment, frame, set_cycle


def measure(drives: int, ios: int = IO_WITH, cycles: int = CYCLES, rounds: int = ROUNDS) -> dict[str, float]:
    """Best-of-``rounds`` CPU us per cycle: frame path, after the reply, and their sum."""
    clock, segment, frame, set_cycle = build(drives, ios)
    best_frame = best_after = float("inf")
    i = 100
    for _ in range(rounds):
        t_frame = t_after = 0.0
        for _ in range(cycles):
            i += 1
            set_cycle(i)
            buf = bytearray(frame)
            t0 = time.thread_time()
            segment.process(buf, defer=True)
            t1 = time.thread_time()
            segment.after_frame()
            clock.advance(0.001)
            t2 = time.thread_time()
            t_frame += t1 - t0
            t_after += t2 - t1
        best_frame = min(best_frame, t_frame / cycles * 1e6)
        best_after = min(best_after, t_after / cycles * 1e6)
    return {"frame_us": best_frame, "after_us": best_after, "total_us": best_frame + best_after}


def profile(drives: int) -> None:
    import cProfile
    import pstats

    clock, segment, frame, set_cycle = build(drives)
    pr = cProfile.Profile()
    for i in range(300):
        set_cycle(i)
        buf = bytearray(frame)
        pr.enable()
        segment.process(buf, defer=True)
        segment.after_frame()
        clock.advance(0.001)
        pr.disable()
    pstats.Stats(pr).sort_stats("tottime").print_stats(25)


def main(argv: list[str]) -> None:
    from gatewaylab import build_info

    if argv[:1] == ["--profile"]:
        profile(int(argv[1]) if len(argv) > 1 else 8)
        return
    counts = [int(a) for a in argv] or [8, 16, 32]
    print(f"EtherCAT segment CPU per 1 kHz cycle, in process ({build_info.summary()[:40]}...), "
          f"best of {ROUNDS} x {CYCLES} cycles, thread CPU time")
    for n in counts:
        r = measure(n)
        print(f"{n:>2} drives + {IO_WITH} io: frame path {r['frame_us']:7.1f} us  after the reply "
              f"{r['after_us']:7.1f} us  total {r['total_us']:7.1f} us", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
