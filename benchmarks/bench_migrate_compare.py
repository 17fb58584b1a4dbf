"""``gatewaylab migrate compare`` on the CiA 402 CSP example, simulated clock: wall time per simulated
second for both gateways together.

One run of ``examples/migrate_cia402_csp.py`` through the esd CAN-EtherCAT and one through the
ECAN-Lite, each on a fresh copy of ``examples/migrate_rig.toml`` (two drives, 500 kbit/s, 1 ms
EtherCAT cycle), then the comparison and the report (plots included). Printed, never asserted.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
import time
from pathlib import Path

from gatewaylab.cli.migrate_rig import compare_config, line_opener
from gatewaylab.migrate.compare import compare
from gatewaylab.migrate.compare_report import write_report
from gatewaylab.migrate.compare_run import GATEWAYS, load_app, run_once

ROOT = Path(__file__).resolve().parent.parent
SECONDS = 1.0


def main() -> None:
    app = load_app(ROOT / "examples" / "migrate_cia402_csp.py")
    opener = line_opener(compare_config(ROOT / "examples" / "migrate_rig.toml", "can0"), "can0")
    recs = []
    walls = []
    for gateway in GATEWAYS:
        w0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            rec = run_once(opener, gateway, app, seconds=SECONDS)
        walls.append(time.perf_counter() - w0)
        recs.append(rec)
        print(f"{gateway[2]:18s} {rec.duration:6.3f} simulated s in {walls[-1]:6.3f} wall s "
              f"({walls[-1] / rec.duration:.3f} wall s per simulated s), {len(rec.bus)} frames")
    w0 = time.perf_counter()
    result = compare(recs[0], recs[1])
    with tempfile.TemporaryDirectory() as tmp:
        write_report(Path(tmp), result, "bench", [], [])
    report_wall = time.perf_counter() - w0
    simulated = sum(r.duration for r in recs)
    total = sum(walls) + report_wall
    print(f"comparison + report (plots): {report_wall:.3f} wall s")
    print(f"both gateways together: {total:.3f} wall s for {simulated:.3f} simulated s = "
          f"{total / simulated:.3f} wall s per simulated s ({simulated / total:.2f}x real time)")
    print(f"verdict: {result.verdict()}")


if __name__ == "__main__":
    main()
