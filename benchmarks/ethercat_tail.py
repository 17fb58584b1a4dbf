"""Where the EtherCAT reply tail comes from: one experiment per setting of the ``[ethercat]`` keys.

``gatewaylab run`` with a mixed rig -- 2 ``ethercat_io`` + 2 ``ethercat_drive`` + an ECAN-Lite on the
segment, 4 CAN drives (1 ms control loops) on two buses, a python-can client sending 2,000 frames/s into
``can0`` -- on one end of a veth pair; SOEM (pysoem) in a namespace on the other end cycling at 1 kHz with
its default 2 ms receive timeout. Printed per run: wrong working counters, the emulator's residence (the
rig's own capture: the kernel's receive time of each request to the send of its reply) p50 / p99 / p99.9 /
max, frames dropped late. ``--busy`` adds a CPU-bound background process (``while True: pass``), as a CI
runner has. Not part of ``make bench`` (docs/decisions.md records its numbers).

Usage: python -m benchmarks.ethercat_tail [--seconds 20] [--busy] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.wire import pct, run_in_namespace, skip_reason, ticks, veth_namespace
from gatewaylab.ethercat.wire_pcap import read_pcap
from gatewaylab.rig.process import RigProcess

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
[[bus]]
name = "can1"
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
[[drive]]
bus = "can0"
node_id = 3
serial = 0x1003
[[drive]]
bus = "can1"
node_id = 4
serial = 0x1004
[[drive]]
bus = "can1"
node_id = 5
serial = 0x1005
[[device]]
kind = "ethercat_io"
name = "io1"
[[device]]
kind = "ethercat_drive"
name = "ecd1"
[[device]]
kind = "ethercat_io"
name = "io2"
[[device]]
kind = "ethercat_drive"
name = "ecd2"
[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can0", "can1"]
[ethercat]
interface = "{interface}"
pcap = "{pcap}"
{extra}
"""
SLAVES = 5


def master(iface: str, seconds: float) -> dict[str, Any]:
    """pysoem: scan, map, OP, ``seconds`` of 1 kHz cycles with SOEM's default timeouts."""
    import pysoem

    m = pysoem.Master()
    m.open(iface)
    if m.config_init() != SLAVES:
        raise RuntimeError("wrong slave count")
    m.config_map()
    if m.state_check(pysoem.SAFEOP_STATE, 2_000_000) != pysoem.SAFEOP_STATE:
        m.read_state()
        raise RuntimeError(f"no SAFEOP: {[(s.name, s.state, hex(s.al_status)) for s in m.slaves]}")
    m.state = pysoem.OP_STATE
    m.send_processdata()
    m.receive_processdata()
    m.write_state()
    for _ in range(400):
        m.send_processdata()
        m.receive_processdata()
        if m.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            break
    else:
        raise RuntimeError("no OP")
    bad = 0
    rtts: list[float] = []
    for _ in ticks(int(seconds * 1000)):
        t0 = time.perf_counter()
        m.send_processdata()
        wkc = m.receive_processdata()
        rtts.append(time.perf_counter() - t0)
        if wkc != m.expected_wkc:
            bad += 1
    m.state = pysoem.INIT_STATE
    m.write_state()
    m.close()
    return {"cycles": len(rtts), "bad_wkc": bad, "rtt_p99_us": 1e6 * pct(rtts, 0.99),
            "rtt_max_us": 1e6 * max(rtts)}


def can_load(endpoint: str, stop: threading.Event, rate: float = 2000.0) -> None:
    """A python-can client sending ``rate`` frames/s into the rig's bus."""
    import can

    with can.Bus(interface="gatewaylab", channel=endpoint) as bus:
        msg = can.Message(arbitration_id=0x321, data=bytes(8), is_extended_id=False)
        period = 1.0 / rate
        t_next = time.perf_counter()
        while not stop.is_set():
            for _ in range(10):
                bus.send(msg, timeout=0.5)
            t_next += 10 * period
            slack = t_next - time.perf_counter()
            if slack > 0:
                time.sleep(slack)


def residence(pcap: bytes) -> list[float]:
    """Request (kernel receive time) -> reply (send) per frame of the capture, in us: a request is followed
    by its reply (the same EtherCAT datagram index) or not at all (dropped: counted as infinitely late)."""
    out: list[float] = []
    pending: dict[int, float] = {}
    for t, frame in read_pcap(pcap):
        if len(frame) < 18 or frame[12:14] != b"\x88\xa4":
            continue
        index = frame[17]
        if frame[6] & 0x02:                       # a reply: the ESC marked the source MAC
            if index in pending:
                out.append(1e6 * (t - pending.pop(index)))
        else:
            if index in pending:                  # the previous request with this index got no reply
                out.append(float("inf"))
            pending[index] = t
    return out


def run(seconds: float, busy: bool, extra: str) -> dict[str, Any]:
    """One experiment; its numbers."""
    busy_proc = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    try:
        with veth_namespace("gl-tail-", "glt") as (ns, emu, mst), tempfile.TemporaryDirectory() as tmp:
            pcap = Path(tmp) / "wire.pcap"
            rig_file = Path(tmp) / "rig.toml"
            rig_file.write_text(RIG.format(interface=emu, pcap=pcap, extra=extra))
            with RigProcess(rig_file, workdir=tmp, timeout=60) as rig:
                stop = threading.Event()
                load = threading.Thread(target=can_load, args=(rig.endpoint("can0"), stop), daemon=True)
                load.start()
                try:
                    proc = run_in_namespace(ns, "benchmarks.ethercat_tail", ["--master", mst, str(seconds)],
                                            timeout=seconds + 300)
                finally:
                    stop.set()
                    load.join(5)
                log = rig.log_text()
            if proc.returncode != 0:
                raise RuntimeError(proc.stderr[-2000:])
            result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
            res = residence(pcap.read_bytes())
    finally:
        if busy_proc is not None:
            busy_proc.kill()
            busy_proc.wait()
    late = [line for line in log.splitlines() if "older than" in line]
    result.update({"res_p50_us": pct(res, 0.5), "res_p99_us": pct(res, 0.99), "res_p999_us": pct(res, 0.999),
                   "res_max_us": max((r for r in res if r != float("inf")), default=float("nan")),
                   "replies": len(res),
                   "late_log_lines": len(late),
                   "dropped_late": sum(int(w.split("dropped ")[1].split(" ")[0]) for w in late)})
    return result


def main() -> None:
    """Parse the command line, run, print one line."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--busy", action="store_true")
    ap.add_argument("--set", action="append", default=[], help="an [ethercat] key = value line")
    ap.add_argument("--master", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.master:
        print(json.dumps(master(args.master[0], float(args.master[1]))))
        return
    skip = skip_reason("pysoem")
    if skip:
        print(skip)
        return
    extra = "\n".join(s.replace("=", " = ", 1) for s in args.set)
    try:
        r = run(args.seconds, args.busy, extra)
    except RuntimeError as exc:
        print(f"{'busy' if args.busy else 'quiet'} {' '.join(args.set) or 'defaults'}: the bring-up failed: "
              f"{str(exc).strip().splitlines()[-1][:300]}", flush=True)
        return
    print(f"{'busy' if args.busy else 'quiet'} {' '.join(args.set) or 'defaults'}: {r['cycles']} cycles, wrong WKC "
          f"{r['bad_wkc']}, residence p50 {r['res_p50_us']:.0f} p99 {r['res_p99_us']:.0f} p99.9 "
          f"{r['res_p999_us']:.0f} max answered {r['res_max_us']:.0f} us (dropped: inf), "
          f"dropped late {r['dropped_late']}, "
          f"master rtt p99 {r['rtt_p99_us']:.0f} max {r['rtt_max_us']:.0f} us", flush=True)



if __name__ == "__main__":
    main()
