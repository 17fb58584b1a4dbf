"""esd CAN-EtherCAT over a veth pair: SOEM (pysoem) at 1 kHz against the emulated gateway on a
500 kbit/s virtual bus, 1,000 CAN frames/s each way through the MDP 5000 counter handshake
(manual 5.1.5). Printed, never asserted: frames lost each way, latency from the gateway's CAN
receive to the master seeing the frame in its inputs (median / p99), late EtherCAT cycles.

Needs root (network namespace + veth); prints why and returns otherwise. GL_BENCH_SECONDS shortens
the run (default 60 s); GL_BENCH_DEBUG=1 adds the latency per 1,000 frames. The master runs in a
subprocess inside the namespace on CPU 0, the emulator's busy-polling wire thread (which also runs
the clock, the bus and the CAN node) on CPU 1.
Both sides stamp with CLOCK_MONOTONIC (one host), so latencies need no clock sync.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import struct
import subprocess
import sys
import time
from typing import Any

OUT_HDR = struct.Struct("<HHH")
IN_HDR = struct.Struct("<HHHH")
TX11 = struct.Struct("<HH8s")
RX_ID, TX_ID = 0x201, 0x123
DRAIN_S = 1.0
START_S = 0.3   # the CAN node starts this long after the gateway entered OP


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def _pin(cpu: int) -> None:
    try:
        os.sched_setaffinity(0, {cpu % (os.cpu_count() or 1)})
    except (AttributeError, OSError):
        pass


# ---------------------------------------------------------------------------------- master side
def _retry(fn: Any, *args: Any) -> Any:
    """A mailbox service repeated when a reply came later than SOEM's timeout (shared machine)."""
    import pysoem

    for attempt in range(6):
        try:
            return fn(*args)
        except (pysoem.WkcError, pysoem.PacketError, pysoem.ConfigMapError, pysoem.MailboxError):
            if attempt == 5:
                raise
            time.sleep(0.2)
    return None


def master(iface: str, seconds: float) -> dict[str, Any]:
    """1 kHz cycles: one new Tx frame per cycle (batched while the gateway has not acknowledged the
    last batch, at most 16), Rx batches read and acknowledged as they come; the time each Rx frame is
    first seen is recorded by its sequence number."""
    import pysoem

    _pin(0)
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
    m.state = pysoem.OP_STATE
    m.send_processdata()
    m.receive_processdata(20_000)
    m.write_state()
    for _ in range(400):
        m.send_processdata()
        m.receive_processdata(20_000)
        if m.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            break
    outputs = bytearray(len(s.output))
    tx_counter = rx_counter = in_tx = 0
    pending: list[int] = []
    generated = committed = 0
    seen: dict[int, int] = {}
    late = 0
    n = int((seconds + START_S + DRAIN_S) * 1000)
    period = 0.001
    t_next = time.perf_counter() + period
    for i in range(n):
        slack = t_next - time.perf_counter() - 0.0003
        if slack > 0:
            time.sleep(slack)
        while time.perf_counter() < t_next:
            pass
        t_next += period
        if i < seconds * 1000:
            pending.append(generated)
            generated += 1
        num_tx = OUT_HDR.unpack_from(outputs, 0)[2]
        if in_tx == tx_counter and pending:
            batch, pending = pending[:16], pending[16:]
            for k, seq in enumerate(batch):
                TX11.pack_into(outputs, 6 + 12 * k, seq & 0xFFFF, TX_ID << 5 | 8, struct.pack("<II", seq, 0))
            tx_counter = (tx_counter + 1) & 0xFFFF
            num_tx = len(batch)
            committed += len(batch)
        OUT_HDR.pack_into(outputs, 0, tx_counter, rx_counter, num_tx)
        s.output = bytes(outputs)
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
    m.state = pysoem.INIT_STATE
    m.write_state()
    m.close()
    return {"cycles": n, "late": late, "tx_generated": generated, "tx_committed": committed,
            "rx_seen": {str(k): v for k, v in seen.items()}}


# ---------------------------------------------------------------------------------- emulator side
class CanNode:
    """The CAN side of the run: sends 1,000 frames/s to the gateway once it is in OP (sequence number in
    the data), records when the gateway's controller received each one (the bus monitor runs at that
    instant) and counts the frames the gateway sends."""

    def __init__(self, clock: Any, bus: Any, gateway: Any, seconds: float) -> None:
        from gatewaylab.bus.frame import CanFrame

        self.CanFrame = CanFrame
        self.clock = clock
        self.gateway = gateway
        self.seconds = seconds
        self.node = bus.attach("node", on_frame=self.heard)
        self.received_at: dict[int, int] = {}
        self.tx_heard: list[int] = []
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
            self.tx_heard.append(struct.unpack_from("<I", frame.data)[0])


def main() -> None:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        print("skipped: needs root and iproute2 to create a namespace and a veth pair")
        return
    from gatewaylab.bus.bus import VirtualBus
    from gatewaylab.common.clock import RealTimeClock
    from gatewaylab.devices.esd_can_ethercat.device import create_esd_gateway
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.ethercat.wire import WireTransport

    seconds = float(os.environ.get("GL_BENCH_SECONDS", "60"))
    tag = f"{os.getpid() % 100000}"
    ns, emu, mst = f"gl-besd-{tag}", f"gbe{tag}e", f"gbe{tag}m"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        subprocess.run(["ip", "link", "add", emu, "type", "veth", "peer", "name", mst, "netns", ns], check=True)
        subprocess.run(["ip", "link", "set", emu, "up"], check=True)
        subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", mst, "up"], check=True)
        clock = RealTimeClock()
        bus = VirtualBus(clock, "can0", bitrate=500_000)
        gw = create_esd_gateway(clock, bus, "esd1")
        node = CanNode(clock, bus, gw, seconds)
        wire = WireTransport(Segment([gw.slave]), emu, clock, drive_clock=True, cpu=1)
        wire.start()
        try:
            proc = subprocess.run(["ip", "netns", "exec", ns, sys.executable, "-m", "benchmarks.bench_esd_can_ethercat",
                                   "--master", mst, str(seconds)], capture_output=True, text=True,
                                  timeout=seconds * 3 + 120, check=False,
                                  cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        finally:
            wire.stop()
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-2000:])
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        with clock.lock:
            stats = gw.statistics()
    finally:
        subprocess.run(["ip", "netns", "del", ns], check=False)
    seen = {int(k): v for k, v in r["rx_seen"].items()}
    lat = [(seen[s] - t) / 1000.0 for s, t in node.received_at.items() if s in seen]
    rx_lost = node.sent - sum(1 for s in range(node.sent) if s in seen)
    if os.environ.get("GL_BENCH_DEBUG"):
        for sec in range(0, node.sent, 1000):
            window = [(seen[q] - node.received_at[q]) / 1000.0 for q in range(sec, min(sec + 1000, node.sent))
                      if q in seen and q in node.received_at]
            print(f"  frames {sec}..: median {statistics.median(window):9.1f} us  max {max(window):9.1f} us")
    tx_lost = r["tx_committed"] - len(node.tx_heard)
    in_order = node.tx_heard == sorted(node.tx_heard)
    print(f"esd CAN-EtherCAT over veth: pysoem at 1 kHz for {seconds:.0f} s (+{DRAIN_S:.0f} s drain), "
          f"500 kbit/s bus, 1,000 frames/s each way")
    print(f"  CAN -> master: sent {node.sent}, seen {node.sent - rx_lost}, lost {rx_lost}; latency CAN receive -> "
          f"master inputs: median {statistics.median(lat) if lat else float('nan'):7.1f} us  "
          f"p99 {_pct(lat, 0.99):7.1f} us  max {max(lat) if lat else float('nan'):7.1f} us")
    print(f"  master -> CAN: generated {r['tx_generated']}, committed {r['tx_committed']}, on the bus "
          f"{len(node.tx_heard)}, lost {tx_lost}, in order {in_order}")
    print(f"  EtherCAT cycles {r['cycles']}, late/lost {r['late']}; gateway 0x2010: FIFO overrun "
          f"{stats[0x35]}, aborted {stats[0x37]}, error frames {stats[0x36]}, cyclic handler avg "
          f"{stats[0x04]} us, CAN handler avg {stats[0x07]} us")
    print("targets: 0 frames lost each way (issue 11)")


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "--master":
        print(json.dumps(master(sys.argv[2], float(sys.argv[3]))))
    else:
        main()
