"""A 100-slave segment from an ENI over a veth pair: SOEM (pysoem) at 1 kHz against ``gatewaylab run`` with
``[ethercat] eni`` + ``esi``: 50 EL1859 (8 digital inputs echoing 8 outputs) and 50 EL3102 (2 analog inputs,
channel 1 a sine) from the test ESI files, each slave given its behaviour rules by a ``[[device]] kind = "esi"``
the ENI places by identity. Printed, never asserted: the rig's start-up (``gatewaylab run`` to its ready
file, and the segment's build in process), wrong working counters (a reply whose counter is not the ENI's),
lost cycles, median / p99 / max round trip.

The bring-up's mapping (SOEM reads 50 PDO assignments over CoE) is asked again when a mailbox answer came
after SOEM's timeout on this shared machine, as the other wire benchmarks do; the paced run has no retry.
Needs root (network namespace + veth); prints why and returns otherwise. GL_BENCH_SECONDS sets the paced
run (default 15 s: about 20 s in all); GL_BENCH_SECONDS=0 measures the start-up alone, three times. The master
runs in a subprocess inside the namespace on CPU 0, the rig's wire thread on CPU 1 blocks as the rig default does
(GL_BENCH_BUSY_POLL=1 busy polls: on a loaded shared machine the busy thread starved the bring-up).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.targets import record
from benchmarks.wire import (
    bench_seconds,
    go_init,
    last_json,
    pin,
    request_op,
    retry,
    rtt_summary,
    run_in_namespace,
    ticks,
    veth_namespace,
)

DATA = Path(__file__).resolve().parent.parent / "tests" / "devices" / "esi" / "data"
DIG = DATA / "GL-test-EL1xxx-EL2xxx.xml"
ANA = DATA / "GL-test-EL3102.xml"
PAIRS = int(os.environ.get("GL_BENCH_ENI_PAIRS", "50"))      # 50 EL1859 + 50 EL3102
P99_LIMIT_US = 500.0
START_LIMIT_S = 2.0
#: said with the start-up: without cached bytecode every start compiles gatewaylab's sources
_BYTECODE = (" (PYTHONDONTWRITEBYTECODE is set: without a __pycache__ every start compiles the sources)"
             if sys.dont_write_bytecode else "")


def _eni(pairs: int) -> str:
    """An ENI (TwinCAT layout, Info and ProcessData per slave) of ``pairs`` EL1859 + EL3102 in turn."""
    from gatewaylab.devices.esi.reader import read_esi_file

    el1859 = read_esi_file(DIG, "EL1859").desc
    el3102 = read_esi_file(ANA, "EL3102").desc
    out = ['<?xml version="1.0" encoding="utf-8"?>', '<EtherCATConfig Version="1.3">', "  <Config>",
           "    <Master><Info><Name>bench</Name></Info></Master>"]
    wkc = 0
    for i in range(2 * pairs):
        d = el1859 if i % 2 == 0 else el3102
        o, n = d.output_bytes * 8, d.input_bytes * 8
        wkc += (2 if o else 0) + (1 if n else 0)
        mailbox = ('      <Mailbox><Send><Start>4096</Start><Length>128</Length></Send><Recv><Start>4224</Start>'
                   '<Length>128</Length></Recv><Protocol>CoE</Protocol></Mailbox>') if d.has_mailbox else ""
        out += ["    <Slave>", f"      <Info><Name>Term {i + 1} ({d.order_code})</Name>"
                f"<PhysAddr>{0x1001 + i}</PhysAddr>"
                f"<AutoIncAddr>{(-i) & 0xFFFF}</AutoIncAddr><VendorId>{d.vendor_id}</VendorId>"
                f"<ProductCode>{d.product_code}</ProductCode><RevisionNo>{d.revision}</RevisionNo></Info>",
                f"      <ProcessData><Send><BitLength>{o}</BitLength></Send><Recv><BitLength>{n}</BitLength></Recv>"
                "</ProcessData>", *([mailbox] if mailbox else []), "    </Slave>"]
    out += [f"    <Cyclic><CycleTime>1000</CycleTime><Frame><Cmd><Cmd>12</Cmd><Cnt>{wkc}</Cnt></Cmd></Frame></Cyclic>",
            "  </Config>", "</EtherCATConfig>", ""]
    return "\n".join(out)


def _rig(interface: str, pairs: int) -> str:
    echo = "\n".join(f'"0x{0x6000 + 0x10 * i:04X}:01" = {{ echo = "0x{0x7000 + 0x10 * i:04X}:01" }}' for i in range(8))
    busy = os.environ.get("GL_BENCH_BUSY_POLL", "0") == "1"
    parts = ['clock = "realtime"']
    for i in range(pairs):
        parts.append(f'[[device]]\nkind = "esi"\nesi = "{DIG}"\ntype = "EL1859"\nname = "dio{i}"\n'
                     f"[device.behaviour]\n{echo}")
        parts.append(f'[[device]]\nkind = "esi"\nesi = "{ANA}"\ntype = "EL3102"\nname = "ai{i}"\n[device.behaviour]\n'
                     '"0x6000:11" = { sine = { amplitude = 10000, period = 0.5 } }')
    parts.append(f'[ethercat]\ninterface = "{interface}"\neni = "bench.eni.xml"\nesi = ["{DATA}"]\ncpu = 1\n'
                 f"busy_poll = {'true' if busy else 'false'}")
    return "\n\n".join(parts) + "\n"


# ---------------------------------------------------------------------------------- master side
def master(iface: str, seconds: float, expected_wkc: int) -> dict[str, Any]:
    """SOEM: bring-up to OP, then ``seconds`` at 1 kHz; the EL1859 outputs change every cycle."""
    import pysoem

    def say(text: str) -> None:
        if os.environ.get("GL_BENCH_DEBUG"):
            print(f"{time.monotonic():.2f} {text}", file=sys.stderr, flush=True)

    pin(0)
    m = pysoem.Master()
    m.sdo_read_timeout = m.sdo_write_timeout = 3_000_000
    m.open(iface)
    found = 0
    for _ in range(10):     # the first scan can meet the rig's wire thread still starting
        found = m.config_init()
        if found > 0:
            break
        time.sleep(0.2)
    if found != 2 * PAIRS:
        return {"error": f"config_init found {found} slaves"}
    say(f"found {found}")
    retry(m.config_map, attempts=6, pause=0.2, errors=("WkcError", "PacketError", "ConfigMapError", "MailboxError"))
    say("mapped")
    m.state_check(pysoem.SAFEOP_STATE, 500_000)
    if not request_op(m, 20_000, 2000):
        m.read_state()
        states = [(i, s.state, hex(s.al_status)) for i, s in enumerate(m.slaves) if s.state != pysoem.OP_STATE]
        return {"error": f"not all {found} slaves reached OP: {states[:10]}"}
    digital = m.slaves[0::2]
    rtts: list[float] = []
    wrong = lost = 0
    n = int(seconds * 1000)
    for i in ticks(n, 0.001):
        for s in digital:
            s.output = bytes([i & 0xFF])
        t0 = time.perf_counter()
        m.send_processdata()
        wkc = m.receive_processdata(2000)
        rtts.append(time.perf_counter() - t0)
        if wkc <= 0:
            lost += 1
        elif wkc != expected_wkc:
            wrong += 1
    m.read_state()
    left = sum(s.state != pysoem.OP_STATE for s in m.slaves)
    out = {"slaves": found, "soem_wkc": m.expected_wkc, "cycles": n, "wrong_wkc": wrong, "lost": lost,
           "left_op": left, **rtt_summary(rtts)}
    go_init(m)
    return out


# ---------------------------------------------------------------------------------- emulator side
def _build_in_process(folder: Path) -> tuple[float, float]:
    """Seconds to parse the rig and build its 100-slave segment in this process (no wire): the first build
    (which imports the device kinds' modules) and a second one (the build alone)."""
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.rig.config import load_rig
    from gatewaylab.rig.runtime import Rig

    took = []
    for _ in range(2):
        t0 = time.perf_counter()
        rig = Rig(load_rig(folder / "rig.toml"), clock=SimulatedClock())
        took.append(time.perf_counter() - t0)
        rig.close()
    return took[0], took[1]


def _start_only(folder: Path, build_s: float) -> None:
    """GL_BENCH_SECONDS=0: the start-up alone, three times (no master): `gatewaylab run` to its ready file and
    the build in process, each printed."""
    from gatewaylab.rig.process import RigProcess

    starts = []
    for _ in range(3):
        t0 = time.perf_counter()
        with RigProcess(folder / "rig.toml", workdir=folder, timeout=120) as rig:
            starts.append(time.perf_counter() - t0)
            slaves = len(rig.info["eni"]["slaves"])
    builds = [build_s, *(_build_in_process(folder)[1] for _ in range(2))]
    print(f"ENI segment start-up only: {slaves} slaves; `gatewaylab run` to its ready file "
          f"{', '.join(f'{s:.2f}' for s in starts)} s (interpreter and imports included, target < {START_LIMIT_S:.0f} "
          f"s){_BYTECODE}; the rig's build in process {', '.join(f'{b:.2f}' for b in builds)} s; load average "
          f"{os.getloadavg()[0]:.1f}")


def main() -> None:
    seconds = bench_seconds(15, "pysoem")
    if seconds is None:
        return
    from gatewaylab.ethercat.eni import parse_eni_xml
    from gatewaylab.rig.process import RigProcess

    eni_text = _eni(PAIRS)
    expected = parse_eni_xml(eni_text).cyclic_wkc or 0
    with tempfile.TemporaryDirectory(prefix="gl-bench-eni-") as tmp, veth_namespace("gl-be-", "glbe") as (ns, emu, mst):
        folder = Path(tmp)
        (folder / "bench.eni.xml").write_text(eni_text)
        (folder / "rig.toml").write_text(_rig(emu, PAIRS))
        first_s, build_s = _build_in_process(folder)
        if seconds <= 0:
            _start_only(folder, build_s)
            return
        t0 = time.perf_counter()
        with RigProcess(folder / "rig.toml", workdir=folder, timeout=120) as rig:
            start_s = time.perf_counter() - t0
            slaves = len(rig.info["eni"]["slaves"])
            proc = run_in_namespace(ns, "benchmarks.bench_eni", ["--master", mst, str(seconds), str(expected)],
                                    seconds * 3 + 180, python_flags=("-X", "faulthandler"))
            result = last_json(proc) if proc.returncode == 0 else {
                "error": f"exit {proc.returncode}: {proc.stderr.strip()[-600:]}"}
    print(f"ENI segment: {slaves} slaves ({PAIRS} EL1859 echo + {PAIRS} EL3102 sine, behaviour rules on), "
          f"pysoem over veth, {seconds:.0f} s at 1 kHz")
    print(f"start-up: `gatewaylab run` to its ready file {start_s:.2f} s (interpreter and imports included)"
          f"{_BYTECODE}; "
          f"the rig's build in process {build_s:.2f} s, {first_s:.2f} s with the device kinds' imports "
          f"(target < {START_LIMIT_S:.0f} s)")
    if "error" in result:
        print(f"master: {result['error']}")
        return
    print(f"SOEM found {result['slaves']}, expected WKC {result['soem_wkc']} (the ENI's {expected}); "
          f"{result['cycles']} cycles: wrong WKC {result['wrong_wkc']}, lost {result['lost']}, slaves out of OP at the "
          f"end {result['left_op']}; round trip median "
          f"{result['median_us']:.0f} us, p99 {result['p99_us']:.0f} us, max {result['max_us']:.0f} us "
          f"(target p99 < {P99_LIMIT_US:.0f} us)")
    met = result["wrong_wkc"] == 0 and result["p99_us"] < P99_LIMIT_US and start_s < START_LIMIT_S
    record("eni", f"{slaves} slaves: {result['wrong_wkc']} wrong WKC, p99 {result['p99_us']:.0f} us, "
                  f"start {start_s:.2f} s (build {build_s:.2f} s)", met)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--master":
        import json

        print(json.dumps(master(sys.argv[2], float(sys.argv[3]), int(sys.argv[4]))))
    else:
        main()
