"""esd CAN-EtherCAT over a veth pair: SOEM (pysoem) at 1 kHz against the emulated gateway on a
500 kbit/s virtual bus, 1,000 CAN frames/s each way through the MDP 5000 counter handshake
(manual 5.1.5), then the ECAN-Lite doing the same work in the same run (one channel, classic CAN at
500 kbit/s, one 128 B chunk each way). Printed, never asserted: frames lost each way, latency from
the gateway's CAN receive to the master seeing the frame in its inputs (median / p99), late
EtherCAT cycles; side by side for both gateways, also the latency from the master writing a frame
into its outputs to the CAN node receiving it.

Needs root (network namespace + veth); prints why and returns otherwise. GL_BENCH_SECONDS shortens
the run (default 60 s per gateway); GL_BENCH_DEBUG=1 adds the latency per 1,000 frames. The master
runs in a subprocess inside the namespace on CPU 0, the emulator's busy-polling wire thread (which
also runs the clock, the bus and the CAN node) on CPU 1 (benchmarks/wire.py).
Both sides stamp with CLOCK_MONOTONIC (one host), so latencies need no clock sync.
"""

from __future__ import annotations

import json
import os
import statistics
import struct
import sys
import time
from typing import Any

from benchmarks.wire import (
    bench_seconds,
    go_init,
    pct,
    pin,
    request_op,
    retry,
    run_master,
    ticks,
    veth_namespace,
)

OUT_HDR = struct.Struct("<HHH")
IN_HDR = struct.Struct("<HHHH")
TX11 = struct.Struct("<HH8s")
RX_ID, TX_ID = 0x201, 0x123
DRAIN_S = 1.0
START_S = 0.3   # the CAN node starts this long after the gateway entered OP
#: the ECAN-Lite master puts at most this many pending frames in one RxPDO image: 2,000 frames/s stay
#: under what a 500 kbit/s bus carries (~3,800 8-byte frames/s), so catching up after a stall never
#: overflows the channel's TX FIFO (the frame stream has no counter handshake to hold the master back)
ECAN_BATCH = 2
MAILBOX_ERRORS = ("WkcError", "PacketError", "ConfigMapError", "MailboxError")


# ---------------------------------------------------------------------------------- master side
def _retry(fn: Any, *args: Any) -> Any:
    """A mailbox service repeated when a reply came later than SOEM's timeout (shared machine)."""
    return retry(fn, *args, attempts=6, pause=0.2, errors=MAILBOX_ERRORS)


def master(iface: str, seconds: float) -> dict[str, Any]:
    """1 kHz cycles: one new Tx frame per cycle (batched while the gateway has not acknowledged the
    last batch, at most 16), Rx batches read and acknowledged as they come; the time each Rx frame is
    first seen is recorded by its sequence number, and the time each Tx frame's batch was first sent."""
    import pysoem

    pin(0)
    m = pysoem.Master()
    m.sdo_read_timeout = m.sdo_write_timeout = 3_000_000
    m.open(iface)
    for _ in range(10):
        if m.config_init() > 0:
            break
        time.sleep(0.2)
    s = m.slaves[0]
    _retry(s.sdo_write, 0xF800, 2, bytes([2]))              # 500 kbit/s (Table 6)
    _retry(s.set_watchdog, "processdata", 1000)
    _retry(m.config_map)
    m.state_check(pysoem.SAFEOP_STATE, 50_000)
    request_op(m, 20_000, 400)
    outputs = bytearray(len(s.output))
    tx_counter = rx_counter = in_tx = 0
    pending: list[int] = []
    generated = committed = 0
    seen: dict[int, int] = {}
    sent_at: dict[int, int] = {}
    late = 0
    n = int((seconds + START_S + DRAIN_S) * 1000)
    for i in ticks(n):
        if i < seconds * 1000:
            pending.append(generated)
            generated += 1
        num_tx = OUT_HDR.unpack_from(outputs, 0)[2]
        batch: list[int] = []
        if in_tx == tx_counter and pending:
            batch, pending = pending[:16], pending[16:]
            for k, seq in enumerate(batch):
                TX11.pack_into(outputs, 6 + 12 * k, seq & 0xFFFF, TX_ID << 5 | 8, struct.pack("<II", seq, 0))
            tx_counter = (tx_counter + 1) & 0xFFFF
            num_tx = len(batch)
            committed += len(batch)
        OUT_HDR.pack_into(outputs, 0, tx_counter, rx_counter, num_tx)
        s.output = bytes(outputs)
        stamp = time.monotonic_ns()
        for seq in batch:
            sent_at[seq] = stamp
        m.send_processdata()
        if m.receive_processdata(20_000) != m.expected_wkc:
            late += 1
            continue
        now = time.monotonic_ns()
        inputs = bytes(s.input)
        in_tx, in_rx, num, _tn = IN_HDR.unpack_from(inputs, 0)
        if in_rx != rx_counter:
            for k in range(num):
                seen.setdefault(struct.unpack_from("<I", inputs, 8 + 10 * k + 2)[0], now)
            rx_counter = in_rx
    go_init(m)
    return {"cycles": n, "late": late, "tx_generated": generated, "tx_committed": committed,
            "rx_seen": {str(k): v for k, v in seen.items()}, "tx_sent_at": {str(k): v for k, v in sent_at.items()}}


def master_ecan(iface: str, seconds: float) -> dict[str, Any]:
    """The same work through the ECAN-Lite: channel 0 classic CAN at 500 kbit/s, N = 1 each way (manual
    5.4.3), 1 kHz; every cycle a new RxPDO image with the frames pending (at most ECAN_BATCH; the same
    image again after a late cycle, which the device takes as a repeat), the TxPDO parsed when its
    sequence is new. Stamps as in ``master``."""
    import pysoem

    from benchmarks.bench_ecanlite import configure_ecan, open_master, preop_session
    from gatewaylab.devices.ecanlite import stream as st

    pin(0)
    m = open_master(iface)
    s = m.slaves[0]
    configure_ecan(s, n=1, channels=1, fd=False, bitrate=500_000)
    _retry(s.set_watchdog, "processdata", 1000)
    _retry(m.config_map)
    m.state_check(pysoem.SAFEOP_STATE, 50_000)
    request_op(m, 20_000, 400)
    rx = st.StreamLayout(multiplier=1, channel_mask=0x01, direction=st.Direction.RX)
    tx = st.StreamLayout(multiplier=1, channel_mask=0x01, direction=st.Direction.TX)
    pending: list[int] = []
    generated = committed = late = parse_errors = 0
    seen: dict[int, int] = {}
    sent_at: dict[int, int] = {}
    previous: bytes | None = None
    image = b""
    seq = 0
    published = True
    n = int((seconds + START_S + DRAIN_S) * 1000)
    for i in ticks(n):
        if i < seconds * 1000:
            pending.append(generated)
            generated += 1
        batch: list[int] = []
        if published:       # the last image reached the device: the next one carries what is pending
            batch, pending = pending[:ECAN_BATCH], pending[ECAN_BATCH:]
            seq = (seq + 1) & 0xFFFF
            image = st.encode_stream(rx, seq, [st.CanPacket.of(0, TX_ID, data=struct.pack("<II", f, 0)) for f in batch])
            committed += len(batch)
        s.output = image
        stamp = time.monotonic_ns()
        for f in batch:
            sent_at[f] = stamp
        m.send_processdata()
        published = m.receive_processdata(20_000) == m.expected_wkc
        if not published:
            late += 1
            continue
        now = time.monotonic_ns()
        inputs = bytes(s.input)
        if st.commit_state(inputs, previous) is not st.Commit.NEW:
            continue
        previous = inputs
        try:
            for frame in st.decode_stream(inputs, tx).frames:
                if frame.can_id == RX_ID:
                    seen.setdefault(struct.unpack_from("<I", frame.data)[0], now)
        except st.StreamError:
            parse_errors += 1
    go_init(m)
    m = preop_session(iface)        # 13.2.5 RX dropped old/new: cache overflows while the master stalled
    rx_cache_drops = sum(int.from_bytes(_retry(m.slaves[0].sdo_read, 0x9020, sub), "little") for sub in (6, 7))
    m.close()
    return {"cycles": n, "late": late, "tx_generated": generated, "tx_committed": committed,
            "parse_errors": parse_errors, "rx_cache_drops": rx_cache_drops,
            "rx_seen": {str(k): v for k, v in seen.items()}, "tx_sent_at": {str(k): v for k, v in sent_at.items()}}


# ---------------------------------------------------------------------------------- emulator side
class CanNode:
    """The CAN side of the run: sends 1,000 frames/s to the gateway once it is in OP (sequence number in
    the data), records when the gateway's controller received each one (the bus monitor runs at that
    instant), and which frames the gateway sends and when this node received them."""

    def __init__(self, clock: Any, bus: Any, gateway: Any, seconds: float) -> None:
        from gatewaylab.bus.frame import CanFrame

        self.CanFrame = CanFrame
        self.clock = clock
        self.gateway = gateway
        self.seconds = seconds
        self.node = bus.attach("node", on_frame=self.heard)
        self.received_at: dict[int, int] = {}
        self.tx_heard: list[int] = []
        self.heard_at: dict[int, int] = {}
        self.sent = 0
        self.started: float | None = None
        bus.add_monitor(self.monitor)
        self.timer = clock.call_every(0.001, self.tick)

    def tick(self) -> None:
        from gatewaylab.ethercat.esc import AlState

        if self.started is None:
            if self.gateway.slave.state != AlState.OP:
                return
            self.started = self.clock.now() + START_S
        if self.clock.now() < self.started:
            return
        if self.clock.now() - self.started >= self.seconds:
            self.timer.cancel()
            return
        self.node.send(self.CanFrame(RX_ID, struct.pack("<II", self.sent, 0)))
        self.sent += 1

    def monitor(self, frame: Any, t: float) -> None:
        if frame.can_id == RX_ID:
            self.received_at[struct.unpack_from("<I", frame.data)[0]] = time.monotonic_ns()

    def heard(self, frame: Any, t: float) -> None:
        if frame.can_id == TX_ID:
            seq = struct.unpack_from("<I", frame.data)[0]
            self.tx_heard.append(seq)
            self.heard_at.setdefault(seq, time.monotonic_ns())


def _run(ns: str, emu: str, mst: str, kind: str, seconds: float) -> tuple[dict[str, Any], CanNode, dict[int, int],
                                                                      list[Any]]:
    """One gateway on a fresh clock and 500 kbit/s bus, the master ``kind`` against it: (master result,
    CAN node, the gateway's counters: 0x2010 for the esd, {} for the ECAN-Lite, the wire's errors)."""
    from gatewaylab.bus import VirtualBus
    from gatewaylab.common.clock import RealTimeClock
    from gatewaylab.devices.ecanlite.device import EcanLiteDevice
    from gatewaylab.devices.esd_can_ethercat.device import create_esd_gateway
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.ethercat.wire import WireTransport

    clock = RealTimeClock()
    bus = VirtualBus(clock, "can0", bitrate=500_000)
    gw: Any = create_esd_gateway(clock, bus, "esd1") if kind == "esd" \
        else EcanLiteDevice(clock, [bus.attach("ecan.mcan0")])
    node = CanNode(clock, bus, gw, seconds)
    wire = WireTransport(Segment([gw.slave]), emu, clock, drive_clock=True, cpu=1)
    wire.start()
    try:
        r = run_master(ns, "benchmarks.bench_esd_can_ethercat", ["--master", kind, mst, str(seconds)],
                       seconds * 3 + 120)
    finally:
        wire.stop()
    stats: dict[int, int] = {}
    if kind == "esd":
        with clock.lock:
            stats = gw.statistics()
    return r, node, stats, list(wire.errors)


def _measure(r: dict[str, Any], node: CanNode) -> dict[str, Any]:
    """Frames lost and latencies (us) each way from one run."""
    seen = {int(k): v for k, v in r["rx_seen"].items()}
    sent_at = {int(k): v for k, v in r["tx_sent_at"].items()}
    to_master = [(seen[s] - t) / 1000.0 for s, t in node.received_at.items() if s in seen]
    to_can = [(t - sent_at[s]) / 1000.0 for s, t in node.heard_at.items() if s in sent_at]
    return {"seen": seen, "to_master": to_master, "to_can": to_can,
            "rx_lost": node.sent - sum(1 for s in range(node.sent) if s in seen),
            "tx_lost": r["tx_committed"] - len(node.tx_heard), "in_order": node.tx_heard == sorted(node.tx_heard)}


def _lat(values: list[float]) -> str:
    median = statistics.median(values) if values else float("nan")
    return f"median {median:7.1f} p99 {pct(values, 0.99):7.1f} us"


def main() -> None:
    seconds = bench_seconds(60)
    if seconds is None:
        return
    with veth_namespace("gl-besd-", "gbe") as (ns, emu, mst):
        r, node, stats, _ = _run(ns, emu, mst, "esd", seconds)
        ecan_r, ecan_node, _, ecan_errors = _run(ns, emu, mst, "ecan", seconds)
    esd, ecan = _measure(r, node), _measure(ecan_r, ecan_node)
    seen, lat, rx_lost = esd["seen"], esd["to_master"], esd["rx_lost"]
    if os.environ.get("GL_BENCH_DEBUG"):
        for sec in range(0, node.sent, 1000):
            window = [(seen[q] - node.received_at[q]) / 1000.0 for q in range(sec, min(sec + 1000, node.sent))
                      if q in seen and q in node.received_at]
            print(f"  frames {sec}..: median {statistics.median(window):9.1f} us  max {max(window):9.1f} us")
    print(f"esd CAN-EtherCAT over veth: pysoem at 1 kHz for {seconds:.0f} s (+{DRAIN_S:.0f} s drain), "
          f"500 kbit/s bus, 1,000 frames/s each way")
    print(f"  CAN -> master: sent {node.sent}, seen {node.sent - rx_lost}, lost {rx_lost}; latency CAN receive -> "
          f"master inputs: median {statistics.median(lat) if lat else float('nan'):7.1f} us  "
          f"p99 {pct(lat, 0.99):7.1f} us  max {max(lat) if lat else float('nan'):7.1f} us")
    print(f"  master -> CAN: generated {r['tx_generated']}, committed {r['tx_committed']}, on the bus "
          f"{len(node.tx_heard)}, lost {esd['tx_lost']}, in order {esd['in_order']}")
    print(f"  EtherCAT cycles {r['cycles']}, late/lost {r['late']}; gateway 0x2010: FIFO overrun "
          f"{stats[0x35]}, aborted {stats[0x37]}, error frames {stats[0x36]}, cyclic handler avg "
          f"{stats[0x04]} us, CAN handler avg {stats[0x07]} us")
    print(f"same run, same work, side by side (ECAN-Lite: channel 0 classic CAN 500 kbit/s, N=1, RX cache 32; "
          f"TxPDO parse errors {ecan_r['parse_errors']}, RX cache overflows 0x9020:06/07 "
          f"{ecan_r['rx_cache_drops']}, emulator frame errors {len(ecan_errors)}):")
    print(f"  {'':<17} {'CAN -> master lost':>18}  {'CAN receive -> master sees':<34} {'master -> CAN lost':>18}  "
          f"master writes -> CAN receive   late cycles")
    for label, run, m in (("esd CAN-EtherCAT", r, esd), ("ECAN-Lite", ecan_r, ecan)):
        print(f"  {label:<17} {m['rx_lost']:>18}  {_lat(m['to_master']):<34} {m['tx_lost']:>18}  "
              f"{_lat(m['to_can']):<29} {run['late']:>11}")
    print("targets: 0 frames lost each way")


if __name__ == "__main__":
    if len(sys.argv) >= 5 and sys.argv[1] == "--master":
        fn = master if sys.argv[2] == "esd" else master_ecan
        print(json.dumps(fn(sys.argv[3], float(sys.argv[4]))))
    else:
        main()
