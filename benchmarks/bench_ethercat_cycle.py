"""CPU time per 1 kHz cycle of an EtherCAT segment, in process (no veth, no root): N CiA 402 drives in CSP
+ 8 ``ethercat_io``, the in-process master's LRW frame (outputs of every slave, then their inputs, as SOEM
maps them).

Two parts are timed (``time.thread_time``, best of ``ROUNDS`` rounds of ``CYCLES`` cycles): the frame
path (``Segment.process``: what the wire thread does between receiving a frame and sending it back) and
the work after the reply (``Segment.after_frame`` and the clock events the cycle scheduled: the drives'
control periods). The sum is what the wire thread spends per cycle; at 1 kHz on one CPU it must stay
well below 1000 us. Printed, never asserted. ``python -m benchmarks.bench_ethercat_cycle [N ...]``;
``--profile N`` prints a cProfile of the pure-Python parts at N drives; ``--scenario N`` (also the last row of
a plain run) the frame path with and without an armed scenario that never fires, same run; ``--armed [N ...]``
the cost of the EtherCAT line faults on the frame path (ethercat/line_faults.py), same run, rounds interleaved:
the frame path as before (``Segment.process``), as the wire dispatches it with no fault armed, and with a
fault armed that never matches (``ec-lose 1 --station 0xFFFE``).
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


def build(drives: int, ios: int = IO_WITH, clock: Any = None) -> tuple[Any, Any, bytearray, Callable[[int], None]]:
    """A segment in OP with ``drives`` enabled drives (CSP) + ``ios`` io; (clock, segment, frame, set_cycle).
    ``clock``: a RealTimeClock to build on (no loop runs it yet), else a new SimulatedClock."""
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.ethercat_drive import EthercatDrive
    from gatewaylab.devices.ethercat_io.device import create_io_slave
    from gatewaylab.ethercat.esc import AlState
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.hosts.ethercat.master import Master

    clock = SimulatedClock() if clock is None else clock

    def advance() -> None:
        if isinstance(clock, SimulatedClock):
            clock.advance(0.001)
        else:
            clock.wait(0.001)   # no loop: wait runs the clock's events

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
        advance()
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
            advance()
    enabled = sum(1 for d in devices if d.drive.state.name == "OPERATION_ENABLED")
    if enabled != drives:
        raise RuntimeError(f"{enabled}/{drives} drives enabled")
    frames.clear()
    m.exchange_process_data()
    advance()
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


def _process_deferred(segment: Any, buf: bytearray) -> bool:
    """``segment.process`` leaving the applications' work for ``after_frame`` (True), or all of it in the frame
    path where the segment has no ``after_frame`` (False: an older segment without ``after_frame``)."""
    if hasattr(segment, "after_frame"):
        segment.process(buf, defer=True)
        return True
    segment.process(buf)
    return False


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
            deferred = _process_deferred(segment, buf)
            t1 = time.thread_time()
            if deferred:
                segment.after_frame()
            clock.advance(0.001)
            t2 = time.thread_time()
            t_frame += t1 - t0
            t_after += t2 - t1
        best_frame = min(best_frame, t_frame / cycles * 1e6)
        best_after = min(best_after, t_after / cycles * 1e6)
    return {"frame_us": best_frame, "after_us": best_after, "total_us": best_frame + best_after}


def _can_load(clock: Any, buses: int = 4, per_bus: int = 2) -> Callable[[], None]:
    """CAN work on ``clock``: ``buses`` 1 Mbit/s buses with ``per_bus`` CiA 402 drives each in CSP, a master
    sending RPDO1 to each drive and SYNC every ms (TPDO1 answers): bench_canopen_drive's 4-bus layout. Returns
    the stop function."""
    from benchmarks.bench_canopen_drive import RPDO, _prepare, drive_groups
    from gatewaylab.bus import CanFrame
    from gatewaylab.devices.canopen_drive.device import Drive

    drives: list[Drive] = []
    plan = []
    with clock.lock:
        for b, (bus, group) in enumerate(drive_groups(clock, buses, per_bus)):
            drives += group
            plan.append((bus.attach(f"master{b}"), [0x200 + d.node.node_id for d in group]))
    clock.wait(0.01)
    with clock.lock:
        for d in drives:
            _prepare(d)
    sync = CanFrame(0x80, b"")
    n = [0]

    def cycle() -> None:
        n[0] += 1
        for master, cob_ids in plan:
            for cob_id in cob_ids:
                master.send(CanFrame(cob_id, RPDO.pack(0x0F, 10 * (n[0] % 1000))))
            master.send(sync)

    with clock.lock:
        timer = clock.call_every(0.001, cycle)

    def stop() -> None:
        with clock.lock:
            timer.cancel()
            for d in drives:
                d.stop()
    return stop


def contention(drives: int = 8, seconds: float = 3.0, rounds: int = 3) -> None:
    """Does the frame path need a process of its own? Answered in one process: the frame path served by a 1 kHz 'wire'
    thread under ``clock.lock`` (as WireTransport with a rig) while a 'rig loop' thread runs the clock's events
    (the EtherCAT drives' control periods), alternating rounds without and with CAN work in that loop (8 CAN
    drives on 4 buses, SYNC + RPDO/TPDO at 1 kHz). Per frame: the round trip (lock wait + frame path) and the
    wire thread's CPU time for it; the difference is the time the frame waited for clock.lock, the GIL or a CPU
    (other processes), and how many frames found clock.lock taken by the loop."""
    import statistics
    import threading

    from benchmarks.wire import pct, pin
    from gatewaylab.common.clock import RealTimeClock

    clock = RealTimeClock()
    clock.ensure_lock()
    _, segment, frame, set_cycle = build(drives, IO_WITH, clock)
    stop_loop = threading.Event()
    passes: list[float] = []

    def loop() -> None:      # the rig's loop: wait for the next deadline, run what is due
        pin(0)
        while not stop_loop.is_set():
            due = clock.next_deadline()
            delay = 0.001 if due is None else min(0.001, max(0.0, due - clock.now()))
            if delay:
                time.sleep(delay)
            t0 = time.perf_counter()
            clock.run_due()
            passes.append(time.perf_counter() - t0)

    def wire(n: int) -> tuple[list[float], list[float], list[float]]:
        rtts: list[float] = []
        cpus: list[float] = []
        blocked: list[float] = []   # frames that found clock.lock taken: how long they waited for it
        lock = clock.lock
        pin(1)        # as WireTransport(cpu=1) in the wire benchmarks
        t_next = time.perf_counter() + 0.001
        for i in range(n):
            while time.perf_counter() < t_next:
                time.sleep(0.0001)
            t_next += 0.001
            set_cycle(i)
            buf = bytearray(frame)
            t0 = time.perf_counter()
            c0 = time.thread_time()
            if not lock.acquire(False):
                lock.acquire()
                blocked.append(time.perf_counter() - t0)
            try:
                segment.process(buf, defer=True)
            finally:
                lock.release()
            rtts.append(time.perf_counter() - t0)     # the frame would be sent here
            cpus.append(time.thread_time() - c0)
            with lock:
                segment.after_frame()
        return rtts, cpus, blocked

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    print(f"contention: {drives} EtherCAT drives + {IO_WITH} io served by a 1 kHz wire thread, a rig loop thread "
          f"running the clock; {seconds:g} s per round, rounds alternate")
    try:
        for r in range(rounds):
            for load in (False, True):
                stop_can = _can_load(clock) if load else None
                passes.clear()
                rtts, cpus, blocked = wire(int(seconds * 1000))
                if stop_can is not None:
                    stop_can()
                waits = [a - b for a, b in zip(rtts, cpus, strict=True)]
                left_op = sum(1 for slave in segment.slaves if slave.state.name != "OP")
                print(f"round {r + 1} {'with CAN work   ' if load else 'without CAN work'}: frame path CPU median "
                      f"{1e6 * statistics.median(cpus):5.0f} us; round trip median "
                      f"{1e6 * statistics.median(rtts):5.0f} "
                      f"p99 {1e6 * pct(rtts, 0.99):6.0f} us; waited p99 {1e6 * pct(waits, 0.99):6.0f} max "
                      f"{1e6 * max(waits):6.0f} us; loop pass (holds clock.lock) median "
                      f"{1e6 * statistics.median(passes):5.0f} p99 {1e6 * pct(passes, 0.99):6.0f} us; "
                      f"found the lock taken "
                      f"{len(blocked)} of {len(rtts)} frames (waited max {1e6 * max(blocked, default=0.0):5.0f} us)"
                      + (f"; INVALID: {left_op} slaves left OP (SM watchdog: the process stalled)" if left_op else ""),
                      flush=True)
    finally:
        stop_loop.set()
        thread.join(1.0)


def faults_cost(drives: int, ios: int = IO_WITH, cycles: int = CYCLES, rounds: int = ROUNDS) -> dict[str, float]:
    """Best-of-``rounds`` CPU us of the frame path per cycle: ``plain`` (``Segment.process``), ``none`` (the wire's
    dispatch, nothing armed), ``armed`` (an armed fault that never matches: every frame parsed and matched)."""
    from gatewaylab.ethercat.line_faults import Kind, LineFault, LineFaults, Match

    clock, segment, frame, set_cycle = build(drives, ios)
    armed = LineFaults()
    armed.add(LineFault(Kind.LOSE, Match(station=0xFFFE), count=1))
    best = {"plain": float("inf"), "none": float("inf"), "armed": float("inf")}
    i = 100
    for _ in range(rounds):
        for variant in best:
            segment.line_faults = armed if variant == "armed" else None
            total = 0.0
            for _ in range(cycles):
                i += 1
                set_cycle(i)
                buf = bytearray(frame)
                t0 = time.thread_time()
                if variant == "plain":
                    segment.process(buf, defer=True)
                else:       # wire.py's dispatch
                    faults = segment.line_faults
                    if faults is not None and faults.engaged:
                        faults.serve(segment, buf, 0.0, defer=True)
                    else:
                        segment.process(buf, defer=True)
                total += time.thread_time() - t0
                segment.after_frame()
                clock.advance(0.001)
            best[variant] = min(best[variant], total / cycles * 1e6)
    if armed.faults[0].details["hits"]:
        raise RuntimeError("the armed fault matched a frame")
    segment.line_faults = None
    return best


def measure_scenario(drives: int, ios: int = IO_WITH, cycles: int = CYCLES,
                     rounds: int = ROUNDS) -> dict[str, float]:
    """The frame path (``Segment.process``) with and without an armed scenario whose milestones never come (a
    MilestoneWatch on the segment waiting for cycle 10**9, a slave in BOOT and an SDO to 0x5FFF: each frame is
    counted and scanned), same segment, rounds alternating; best-of-``rounds`` CPU us per cycle each way."""
    from gatewaylab.ethercat.esc import AlState
    from gatewaylab.ethercat.milestones import MilestoneWatch

    clock, segment, frame, set_cycle = build(drives, ios)

    def never() -> None:
        raise AssertionError("the benchmark's scenario fired")

    watch = MilestoneWatch(segment)
    watch.on_cycles(10**9, never)
    watch.on_state(segment.slaves[-1], AlState.BOOT, never)
    watch.on_sdo(segment.slaves[0], 0x5FFF, never)
    best = {"plain_us": float("inf"), "armed_us": float("inf")}
    i = 100
    for _ in range(rounds):
        for key in best:
            if key == "armed_us":
                watch.attach()
            t_frame = 0.0
            for _ in range(cycles):
                i += 1
                set_cycle(i)
                buf = bytearray(frame)
                t0 = time.thread_time()
                segment.process(buf, defer=True)
                t_frame += time.thread_time() - t0
                segment.after_frame()
                clock.advance(0.001)
            watch.detach()
            best[key] = min(best[key], t_frame / cycles * 1e6)
    return best


def _scenario_row(n: int) -> None:
    r = measure_scenario(n)
    print(f"{n:>2} drives + {IO_WITH} io: frame path {r['plain_us']:7.1f} us, with an armed scenario that never "
          f"fires {r['armed_us']:7.1f} us ({r['armed_us'] / r['plain_us']:.2f}x)", flush=True)


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

    if argv[:1] == ["--contention"]:
        contention(int(argv[1]) if len(argv) > 1 else 8)
        return
    if argv[:1] == ["--armed"]:
        print(f"EtherCAT frame path per 1 kHz cycle with the fault machinery, in process "
              f"({build_info.summary()[:40]}...), best of {ROUNDS} x {CYCLES} cycles each, interleaved")
        for n in [int(a) for a in argv[1:]] or [8, 32]:
            r = faults_cost(n)
            print(f"{n:>2} drives + {IO_WITH} io: frame path {r['plain']:7.1f} us plain, {r['none']:7.1f} us no fault "
                  f"armed, {r['armed']:7.1f} us a fault armed that never matches "
                  f"({r['armed'] - r['plain']:+.1f} us)", flush=True)
        return
    if argv[:1] == ["--scenario"]:
        _scenario_row(int(argv[1]) if len(argv) > 1 else 8)
        return
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
    _scenario_row(counts[0])


if __name__ == "__main__":
    main(sys.argv[1:])
