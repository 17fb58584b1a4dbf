"""``gatewaylab migrate``: ``config`` (esd ENI or startup list -> ECAN-Lite ENI + report), ``esi``
(a device's ESI file) and ``compare`` (one application through both gateways, side by side),
docs/migration-esd-to-ecanlite.md."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.hosts.ethercat.pysoem_backend import PysoemBackend
from gatewaylab.migrate.config import DEVICES, device_slave, ecanlite_slave, esi_text, find_esd, read_live, report
from gatewaylab.migrate.eni import EniError, SlaveConfig, format_writes, parse_eni, parse_writes, write_eni
from gatewaylab.migrate.translate import DEFAULT_FALLBACK_RATE, translate

_EPILOG = """\
examples:
  gatewaylab migrate config esd.xml -o ecanlite.xml --report report.md
  gatewaylab migrate config startup.txt -o ecanlite.xml --channel 2 --complete-access
  gatewaylab migrate config -i eth0 -p 1 -o ecanlite.xml --report report.md
  gatewaylab migrate esi --device ecanlite -o ECAN-Lite.xml

INPUT is an ENI (ETG.2100 XML) holding an esd CAN-EtherCAT (vendor 0x17, product 2), or a plain
list of CoE startup writes, one per line: INDEX:SUB TYPE VALUE [ca] (TYPE u8/u16/u32/u64/hex).
The output is an ENI with the ECAN-Lite in the esd's place (or, for an output file ending .txt,
the startup list). Everything not translated one-to-one is listed in the report.
"""


def _read_wire(ifname: str, position: int) -> SlaveConfig:
    """The running esd gateway at ``position`` on ``ifname`` (SOEM through pysoem, needs root)."""
    backend = PysoemBackend(ifname)
    try:
        ident = backend.slaves()[position] if position < len(backend.slaves()) else None
        if ident is None:
            raise ConfigError(f"no slave at position {position} on {ifname}")
        desc = device_slave("esd_can_ethercat").desc
        if (ident.vendor_id, ident.product_code) != (desc.vendor_id, desc.product_code):
            raise ConfigError(f"slave {position} on {ifname} is vendor 0x{ident.vendor_id:X} product "
                             f"0x{ident.product_code:X}, not an esd CAN-EtherCAT")
        return SlaveConfig(f"esd CAN-EtherCAT at {ifname}:{position}", ident.vendor_id, ident.product_code,
                           ident.revision, ident.serial, init_cmds=tuple(read_live(backend, position)))
    finally:
        backend.close()


def cmd_config(args: argparse.Namespace) -> int:
    """``migrate config``: an esd ENI, startup list or live esd -> the ECAN-Lite ENI and the report."""
    if (args.input is None) == (args.ifname is None):
        raise ConfigError("give either INPUT or -i IFNAME (with -p POS)")
    if args.ifname is not None:
        esd = _read_wire(args.ifname, args.position)
        source = f"{args.ifname} position {args.position}"
    else:
        try:
            text = Path(args.input).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{args.input}: cannot read it: {getattr(exc, 'strerror', None) or exc}") from None
        source = Path(args.input).name
        try:
            if text.lstrip().startswith("<"):
                esd = find_esd(parse_eni(text))
            else:
                esd = SlaveConfig("esd CAN-EtherCAT", 0x17, 2, init_cmds=tuple(parse_writes(text)))
        except EniError as exc:   # the reader's errors name the line; the user needs the file too
            raise EniError(f"{args.input}: {exc}") from None
    tr = translate(esd.init_cmds, args.channel, args.complete_access, args.bitrate)
    out = Path(args.output)
    if out.suffix == ".txt":
        out.write_text(format_writes(tr.cmds), encoding="utf-8")
    else:
        out.write_text(write_eni([ecanlite_slave(esd, tr)]), encoding="utf-8")
    md = report(source, esd.init_cmds, tr)
    if args.report:
        Path(args.report).write_text(md, encoding="utf-8")
    print(f"{out}: ECAN-Lite MCAN{tr.channel}, N = {tr.multiplier} ({128 * tr.multiplier} B each way), "
          f"{len(tr.cmds)} InitCmds, {len(tr.notes)} notes" + (f"; report {args.report}" if args.report else ""))
    for n in tr.notes:
        print(f"  note: {n.topic}: {n.reason}. Closest: {n.closest}.")
    return 0


def cmd_esi(args: argparse.Namespace) -> int:
    """``migrate esi``: write the ESI file of a device kind."""
    Path(args.output).write_text(esi_text(args.device), encoding="utf-8")
    print(f"{args.output}: ESI of {args.device}")
    return 0


_COMPARE_EPILOG = """\
examples:
  gatewaylab migrate compare --rig examples/migrate_rig.toml --bus can0 \\
      --app examples/migrate_cia402_csp.py --report report/ --seconds 0.5

RIG holds the buses and drives (no gateways). APP.py defines run(bus) taking a can.BusABC (and
optionally seconds=S, given by --seconds). The application runs once through an esd CAN-EtherCAT
and once through an ECAN-Lite (MCAN channel 0) attached to BUS, each on a fresh copy of the rig,
in process on a simulated clock (deterministic: the same inputs give the same report), or with
--wire in real time: the rig on one end of a veth pair, SOEM (pysoem) on the other end inside a
network namespace (root; both are removed again however the run ends). DIR gets both buses'
traces (python-can CSV), report.md, report.html, latency.png and timeline.png.

exit status: 0 the CAN traffic is the same (timing differences alone do not count), 1 it
differs, 2 usage error (bad arguments, rig or application file), 3 the application or a gateway
failed during a run.
"""


def cmd_compare(args: argparse.Namespace) -> int:
    """``migrate compare``: the application through both gateways on copies of the rig; verdict, report, exit code."""
    from gatewaylab.cli.migrate_rig import open_compare
    from gatewaylab.migrate.compare import compare
    from gatewaylab.migrate.compare_report import latency_summary, read_recording, write_recording, write_report
    from gatewaylab.migrate.compare_run import GATEWAYS, Runner, load_app, takes_seconds

    if args.seconds is not None and args.seconds <= 0:
        raise ConfigError(f"--seconds {args.seconds}: must be positive")
    app = load_app(args.app)
    if args.seconds is not None and not takes_seconds(app):
        raise ConfigError(f"{args.app}: run() takes no seconds parameter, so --seconds cannot be used")
    runner: Runner = open_compare(args.rig, args.bus, args.wire)
    folder = Path(args.report)
    folder.mkdir(parents=True, exist_ok=True)
    traces: list[str] = []
    durations = []
    for gateway in GATEWAYS:
        try:
            with contextlib.redirect_stdout(sys.stderr):   # stdout keeps the verdict (or the JSON) alone
                rec = runner(gateway, Path(args.app), args.seconds, args.cycle_us)
        except Exception as exc:     # the application's own errors included: report, exit 3
            print(f"gatewaylab: {args.app} through {gateway[2]} failed: {type(exc).__name__}: {exc}")
            return 3
        traces += [p.name for p in write_recording(folder, gateway[1], rec)]
        durations.append(rec.duration)
    # the report is made from the trace files, as anyone re-reading them would see it
    a, b = (read_recording(folder, g[1], g[2], d) for g, d in zip(GATEWAYS, durations))
    result = compare(a, b)
    setup = (("rig", Path(args.rig).name), ("bus", args.bus), ("application", Path(args.app).name),
             ("clock", ("real time over veth pairs (SOEM through pysoem)" if args.wire else "simulated")
                       + f", EtherCAT cycle {args.cycle_us} us"),
             ("seconds", "-" if args.seconds is None else f"{args.seconds:g}"),
             ("gateways", f"{a.gateway} (its CAN port) / {b.gateway} (N = 3)"))
    md = write_report(folder, result, f"migrate compare: {Path(args.app).name}", setup, traces)
    if args.json:
        print(json.dumps({"identical": result.identical, "verdict": result.verdict(), "report": str(md),
                          "frames": [len(a.bus), len(b.bus)],
                          "only": [len(result.only_in(0)), len(result.only_in(1))],
                          "order": len(result.moved), "payload": len(result.payload),
                          "latency": {a.gateway: latency_summary(result.latency_a),
                                      b.gateway: latency_summary(result.latency_b)}}, indent=2))
    else:
        print(result.verdict())
    return 0 if result.identical else 1


def _channel(text: str) -> int:
    try:
        k = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 <= k <= 3:
        raise argparse.ArgumentTypeError(f"channel {k} is not 0..3")
    return k


def add_subcommand(sub: Any) -> None:
    """Register ``gatewaylab migrate`` (cli/main.py EXTRA_SUBCOMMANDS)."""
    m = sub.add_parser("migrate", help="esd CAN-EtherCAT -> ECAN-Lite migration (config translation, ESI)",
                       description="esd CAN-EtherCAT -> ECAN-Lite migration kit.")
    msub = m.add_subparsers(dest="migrate_command", metavar="COMMAND")
    c = msub.add_parser("config", help="translate an esd ENI / startup list into the ECAN-Lite's",
                        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    c.add_argument("input", metavar="INPUT", nargs="?", help="esd ENI (XML) or startup-write list")
    c.add_argument("-i", "--interface", dest="ifname", metavar="IFNAME",
                   help="read a running esd gateway's dictionary over this interface instead (SOEM, root)")
    c.add_argument("-p", "--position", type=int, default=0, metavar="POS", help="its position on the line (0)")
    c.add_argument("-o", "--output", required=True, metavar="FILE", help="ECAN-Lite ENI (or .txt startup list)")
    c.add_argument("--report", metavar="FILE", help="Markdown translation report")
    c.add_argument("--channel", type=_channel, default=0, metavar="K", help="MCAN channel 0..3 for the esd's port")
    c.add_argument("--complete-access", action="store_true", help="write 0x1C12/0x1C13 by complete access")
    c.add_argument("--bitrate", type=int, default=DEFAULT_FALLBACK_RATE, metavar="BIT/S",
                   help="rate for an esd set to autobaud (default %(default)s)")
    c.set_defaults(func=cmd_config)
    e = msub.add_parser("esi", help="write a device's ESI file")
    e.add_argument("--device", required=True, choices=DEVICES)
    e.add_argument("-o", "--output", required=True, metavar="FILE")
    e.set_defaults(func=cmd_esi)
    k = msub.add_parser("compare", help="run one application through both gateways and compare the CAN traffic",
                        epilog=_COMPARE_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    k.add_argument("--rig", required=True, metavar="RIG.toml", help="buses and drives, no gateways")
    k.add_argument("--bus", required=True, metavar="BUS", help="the [[bus]] both gateways are attached to")
    k.add_argument("--app", required=True, metavar="APP.py", help="defines run(bus) taking a can.BusABC")
    k.add_argument("--report", default="compare-report", metavar="DIR",
                   help="folder for traces and report (default %(default)s)")
    k.add_argument("--seconds", type=float, metavar="S", help="passed to run(bus, seconds=S)")
    k.add_argument("--cycle-us", type=int, default=1000, metavar="US", help="EtherCAT cycle (default %(default)s)")
    k.add_argument("--wire", action="store_true",
                   help="real time over a veth pair with SOEM (pysoem) as master (root); not deterministic")
    k.add_argument("--json", action="store_true", help="print the summary as JSON instead of the verdict line")
    k.set_defaults(func=cmd_compare)

    def no_command(args: argparse.Namespace) -> int:
        m.print_help()
        return 2
    m.set_defaults(func=no_command)


__all__ = ["add_subcommand"]
