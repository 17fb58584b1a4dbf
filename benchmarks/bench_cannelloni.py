"""What a cannelloni tunnel adds: latency and loss between two rigs at 30 % and 80 % bus load.

Rig A (this process) has a drive (node 3), a load node and a prober; rig B (`gatewaylab run`) has a
drive (node 2); their can0 buses are joined by a tunnel on 127.0.0.1 (buffer timeout 200 us). The
load node sends 8-byte frames (id 0x7F0) that fill the given share of the bus and cross the tunnel
like any frame. The prober alternates SDO uploads of 0x1000 from node 2 (through the tunnel) and
node 3 (local) every 20 ms; the tunnel's added latency per direction is half the difference of the
median round trips, loss the requests never answered. TUNNEL_SECONDS per load (default 10). Real
time: a machine busy with other work shows its own delays. Printed, not asserted.
"""

from __future__ import annotations

import os
import statistics
import tempfile
from pathlib import Path

from gatewaylab.bus import CanFrame
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.process import RigProcess, free_udp_ports, rig_toml
from gatewaylab.rig.runtime import Rig

SECONDS = float(os.environ.get("TUNNEL_SECONDS", "10"))
PROBE_EVERY = 0.02
LOAD_TICK = 0.01
FRAME_TIME = 0.000125       # an 8-byte classic base frame with typical stuffing at 1 Mbit/s
UPLOAD = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])


def rig_dict(node_id: int, local: int, remote: int) -> dict[str, object]:
    return {"clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}],
            "drive": [{"bus": "can0", "node_id": node_id, "serial": 0x2000 + node_id, "name": f"axis{node_id}"}],
            "tunnel": [{"kind": "cannelloni", "bus": "can0", "local": f"127.0.0.1:{local}",
                        "remote": f"127.0.0.1:{remote}", "timeout_us": 200}]}


def measure(rig: Rig, load: float) -> str:
    clock = rig.clock
    bus = rig.buses["can0"]
    pending: dict[int, float] = {}
    rtts: dict[int, list[float]] = {2: [], 3: []}
    sent = {2: 0, 3: 0}

    def on_frame(frame: CanFrame, t: float) -> None:
        node = frame.can_id - 0x580
        if node in pending:
            rtts[node].append(t - pending.pop(node))

    prober = bus.attach("prober", on_frame=on_frame)
    loader = bus.attach("load")
    per_tick = round(load / 100 * LOAD_TICK / FRAME_TIME)
    filler = CanFrame(0x7F0, bytes(8))
    turn = [2]

    def probe() -> None:
        node = turn[0]
        turn[0] = 5 - node
        if node not in pending:               # the previous request of this node is answered
            pending[node] = clock.now()
            sent[node] += 1
            prober.send(CanFrame(0x600 + node, UPLOAD))

    def fill() -> None:
        for _ in range(per_tick - len(loader.tx_queue)):
            loader.send(filler)

    timers = [clock.call_every(PROBE_EVERY, probe), clock.call_every(LOAD_TICK, fill)] if per_tick else \
        [clock.call_every(PROBE_EVERY, probe)]
    bus.stats.busy_time = 0.0
    bus.stats.since = clock.now()
    end = clock.now() + SECONDS
    rig.run(until=lambda: clock.now() >= end, signals=False)
    for timer in timers:
        timer.cancel()
    measured_load = bus.load_percent()
    drained = clock.now() + 1.0
    rig.run(until=lambda: clock.now() >= drained, signals=False)
    bus.detach(prober)
    bus.detach(loader)
    remote, local = rtts[2], rtts[3]
    if not remote or not local:
        return (f"load {load:.0f} % (measured {measured_load:.0f} %): no answers (remote {len(remote)}, "
                f"local {len(local)})")
    added = (statistics.median(remote) - statistics.median(local)) / 2
    p99 = sorted(remote)[int(0.99 * (len(remote) - 1))]
    lost = sent[2] - len(remote)
    return (f"load {load:.0f} % (measured {measured_load:.0f} %): added latency per direction {added * 1e3:.2f} ms "
            f"(round trip through the tunnel: median {statistics.median(remote) * 1e3:.2f} ms, p99 {p99 * 1e3:.2f} ms; "
            f"local {statistics.median(local) * 1e3:.2f} ms), lost {lost}/{sent[2]} requests")


def main() -> None:
    port_a, port_b = free_udp_ports(2)
    with tempfile.TemporaryDirectory(prefix="bench-cannelloni-") as folder:
        b_file = Path(folder) / "b.toml"
        b_file.write_text(rig_toml(rig_dict(2, port_b, port_a)))
        with RigProcess(b_file, workdir=folder, timeout=120):
            rig = Rig(parse_rig(rig_dict(3, port_a, port_b)), clock=RealTimeClock())
            try:
                rig.start()
                print(f"cannelloni tunnel between two rigs on 127.0.0.1, {SECONDS:.0f} s per load:")
                for load in (0.0, 30.0, 80.0):
                    print(f"  {measure(rig, load)}")
            finally:
                rig.close()


if __name__ == "__main__":
    main()
