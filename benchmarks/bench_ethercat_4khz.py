"""A 4 kHz (250 us) EtherCAT segment over a veth pair with SOEM (pysoem): one ECAN-Lite at N=3 (four CAN
FD channels, 1,000 frames/s each way on each) followed by 4 EtherCAT CiA 402 drives in CSP, next to one
``ethercat_io`` paced the same way in the same run.

The master puts 4 frames (one per channel) in an RxPDO image every ms, i.e. every fourth cycle, parses
the TxPDO every cycle and runs a CSP ramp on every drive every cycle. Target: 0 CAN frames lost either
way, 0 wrong working counters (a frame later than 20 ms counts as one), the p99 cycle round trip printed
beside ethercat_io's. Printed, never asserted. The master and the emulator side are bench_ecanlite's
(``rate`` and ``drives``); needs root (namespace + veth); GL_BENCH_SECONDS shortens the run (default 60 s).
"""

from __future__ import annotations

from benchmarks.bench_ecanlite import N, measure, report
from benchmarks.targets import record
from benchmarks.wire import bench_seconds, veth_namespace

RATE = 4000.0
DRIVES = 4


def main() -> None:
    seconds = bench_seconds(60, "pysoem")
    if seconds is None:
        return
    with veth_namespace("gl-b4k-", "glk") as (ns, emu, mst):
        try:
            io, ecan, counts = measure(ns, emu, mst, seconds, RATE, DRIVES)
        except RuntimeError as exc:
            record("4khz", f"the master failed: {str(exc).strip().splitlines()[-1:]}", False)
            raise
    print(f"4 kHz segment over veth, pysoem: ECAN-Lite N={N} + {DRIVES} drives (CSP, enabled "
          f"{ecan['enabled']}/{DRIVES}, faults {ecan['faults']}) for {seconds:g} s, 4 CAN FD channels x "
          f"1,000 frames/s each way")
    to_master, to_bus = report(io, ecan, counts, RATE)
    text = (f"lost {to_master} to the master, {to_bus} to the buses; wrong WKC {ecan['late']} "
            f"of {ecan['cycles']}; p99 {ecan['p99_us']:.0f} us (ethercat_io alone {io['p99_us']:.0f} us)")
    met = to_master == 0 and to_bus == 0 and ecan["late"] == 0 and not ecan["faults"]
    print(f"target: 0 CAN frames lost, 0 wrong working counters: {'met' if met else 'NOT met'}")
    record("4khz", text, met)


def targets() -> None:
    """The whole benchmark is the target."""
    main()


if __name__ == "__main__":
    main()
