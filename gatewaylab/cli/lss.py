"""``gatewaylab lss``: every CiA 305 LSS master service on any bus of a running rig (or any python-can bus).

The services are those of the IDX guide's LSS chapter (3.5) and CiA 305: switch state global and
selective, configure node-ID, configure and activate bit timing, store, inquire the identity parts
and the node-ID, identify remote slaves in address ranges, identify non-configured slaves and
Fastscan. The protocol is the project's own sans-I/O :class:`~.lss.LssMaster` on a real-time clock;
this module only moves frames between it and a python-can bus. ``--explain`` prints each frame with
its meaning (the decoder of ``gatewaylab demo``) and Fastscan as the bisection it is.

A slave keeps its LSS state between runs, so services compose like the steps of the guide::

    gatewaylab lss unix:/tmp/gl/can0.sock fastscan            # selects the unconfigured drive
    gatewaylab lss unix:/tmp/gl/can0.sock set-node-id 4
    gatewaylab lss unix:/tmp/gl/can0.sock store
    gatewaylab lss unix:/tmp/gl/can0.sock switch-global waiting
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

import can

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.explain import explain
from gatewaylab.canopen.lss import (
    BIT_TIMING_TABLE,
    LSS_SLAVE_COB_ID,
    Cs,
    LssAddress,
    LssError,
    LssMaster,
    LssState,
    LssTimeout,
)
from gatewaylab.canopen.monitor import FastscanNarrator
from gatewaylab.cli.target import USAGE, Unreachable, bus_target, open_endpoint
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.common.endpoint import EndpointError
from gatewaylab.common.errors import ConfigError, GatewaylabError

__all__ = ["LssSession", "add_subcommand", "cmd_lss"]


_PARTS = ("vendor", "product", "revision", "serial")
_INQUIRE = {"vendor": Cs.INQUIRE_VENDOR, "product": Cs.INQUIRE_PRODUCT, "revision": Cs.INQUIRE_REVISION,
            "serial": Cs.INQUIRE_SERIAL, "node-id": Cs.INQUIRE_NODE_ID}


class LssSession:
    """One LSS master on a python-can bus: runs one service at a time to its result."""

    def __init__(self, bus: can.BusABC, timeout: float = 0.1,
                 say: Callable[[str], None] | None = None) -> None:
        self.bus = bus
        self.clock = RealTimeClock()
        self.master = LssMaster(self.clock, self._send, timeout=timeout)
        self._say = say
        self._fastscan = FastscanNarrator(self._bit) if say is not None else None

    def _bit(self, sub: int, bit: int, value: int) -> None:
        if self._say is not None:
            self._say(f"   bit {bit} of {_PARTS[sub]}: {value}")

    def _send(self, frame: CanFrame) -> None:
        if self._fastscan is not None:
            self._fastscan.request(frame.data)   # first says what the previous request found
        if self._say is not None:
            self._say(f"-> {frame.can_id:03X} {frame.data.hex(' ').upper()}  {explain(frame)}")
        self.bus.send(frame.to_message())

    def run(self, start: Callable[[Callable[[Any], None]], None]) -> Any:
        """Start a service (``lambda cb: master.fast_scan(cb)``) and serve frames and timers until its
        callback fires; an :class:`LssError` result is raised."""
        results: list[Any] = []
        start(results.append)
        while not results:
            due = self.clock.next_deadline()
            wait = 0.05 if due is None else min(0.05, max(0.0, due - self.clock.now()))
            msg = self.bus.recv(wait)
            if msg is not None and not msg.is_error_frame:
                frame = CanFrame.from_message(msg)
                if frame.can_id == LSS_SLAVE_COB_ID:
                    if self._say is not None:
                        self._say(f"<- {frame.can_id:03X} {frame.data.hex(' ').upper()}  {explain(frame)}")
                    if self._fastscan is not None and frame.data[:1] == bytes((Cs.IDENTIFY_SLAVE,)):
                        self._fastscan.answer()
                self.master.on_frame(frame, self.clock.now())
            self.clock.run_due()
        if self._fastscan is not None:
            self._fastscan.flush()   # report the last bisection step
        result = results[0]
        if isinstance(result, LssError):
            raise result
        return result


def _address_text(address: LssAddress) -> str:
    return (f"vendor 0x{address.vendor_id:08X} product 0x{address.product_code:08X} "
            f"revision 0x{address.revision:08X} serial 0x{address.serial:08X}")


def _u32(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r} (hex with 0x)") from None
    if not 0 <= value <= 0xFFFFFFFF:
        raise argparse.ArgumentTypeError(f"{text} does not fit 32 bits")
    return value


def _ranged(name: str, low: int, high: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        value = _u32(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{name} must be {low}..{high}, got {text}")
        return value
    return parse


def _node_id(text: str) -> int:
    """A node-ID LSS may configure: 1..127, or 0xFF (unconfigured; CiA 305 clause 8.3.2.1)."""
    value = _u32(text)
    if not (1 <= value <= 127 or value == 0xFF):
        raise argparse.ArgumentTypeError(f"node-ID must be 1..127 or 0xFF (unconfigured), got {text}")
    return value


def _service(args: argparse.Namespace, session: LssSession) -> tuple[str, Any]:
    """Run the service the command line names; returns (text, json value)."""
    m = session.master
    cmd = args.lss_command
    if cmd == "switch-global":
        state = LssState.CONFIGURATION if args.state == "configuration" else LssState.WAITING
        session.run(lambda cb: m.switch_state_global(state, cb))
        return f"all slaves switched to LSS {args.state} state", args.state
    if cmd == "switch-selective":
        address = LssAddress(args.vendor, args.product, args.revision, args.serial)
        found = session.run(lambda cb: m.switch_state_selective(address, cb))
        text = (f"selected {_address_text(address)}: now in configuration state" if found
                else f"no slave with {_address_text(address)} answered")
        return text, bool(found)
    if cmd == "set-node-id":
        try:
            session.run(lambda cb: m.configure_node_id(args.node_id, cb))
        except LssTimeout:
            raise LssTimeout(f"no slave in LSS configuration state answered configure node-ID {args.node_id}: "
                             "select one first (`gatewaylab lss TARGET switch-selective VENDOR PRODUCT REVISION "
                             "SERIAL`, `fastscan`, or `switch-global configuration` with a single slave on the "
                             "bus)") from None
        return f"node-ID 0x{args.node_id:02X} ({args.node_id}) configured", args.node_id
    if cmd == "set-bit-timing":
        session.run(lambda cb: m.configure_bit_timing(args.index, cb))
        rate = BIT_TIMING_TABLE[args.index] if args.index < len(BIT_TIMING_TABLE) else None
        return f"bit timing index {args.index} ({rate or 'reserved'} bit/s) configured", args.index
    if cmd == "activate-bit-timing":
        session.run(lambda cb: m.activate_bit_timing(args.delay_ms, cb))
        return f"all slaves switch bit timing after {args.delay_ms} ms", args.delay_ms
    if cmd == "store":
        session.run(lambda cb: m.store_configuration(cb))
        return "configuration stored", True
    if cmd == "inquire":
        names = list(_INQUIRE) if args.what == "all" else [args.what]
        values: dict[str, int] = {}
        for name in names:
            cs = _INQUIRE[name]
            values[name] = session.run(lambda cb: m.inquire(cs, cb))  # noqa: B023 (run returns before the next cs)
        return "  ".join(f"{k} 0x{v:08X}" if k != "node-id" else f"node-id 0x{v:02X}" for k, v in values.items()), \
            values
    if cmd == "identify":
        count = session.run(lambda cb: m.identify_remote_slave(args.vendor, args.product, args.revision_low,
                                                               args.revision_high, args.serial_low,
                                                               args.serial_high, cb))
        return f"{count} slave(s) in the range answered", count
    if cmd == "identify-unconfigured":
        count = session.run(lambda cb: m.identify_non_configured(cb))
        return f"{count} non-configured slave(s) answered", count
    if cmd == "fastscan":
        address = session.run(lambda cb: m.fast_scan(cb))
        if address is None:
            return "no non-configured slave answered", None
        text = f"found {_address_text(address)} (now in configuration state)"
        result: dict[str, Any] = {"vendor": address.vendor_id, "product": address.product_code,
                                  "revision": address.revision, "serial": address.serial}
        if args.node_id is not None:
            session.run(lambda cb: m.configure_node_id(args.node_id, cb))
            text += f"\nnode-ID 0x{args.node_id:02X} ({args.node_id}) configured"
            result["node_id"] = args.node_id
            if args.store:
                session.run(lambda cb: m.store_configuration(cb))
                text += "\nconfiguration stored"
        return text, result
    raise ConfigError(f"unknown LSS service {cmd!r}")


def cmd_lss(args: argparse.Namespace) -> int:
    """``gatewaylab lss TARGET SERVICE ...``: one LSS service, its result on stdout."""
    try:
        endpoint = bus_target(args.target, args.bus)
    except EndpointError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USAGE
    say = print if args.explain else None
    try:
        bus = open_endpoint(endpoint, name="gatewaylab-lss")
    except Unreachable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    try:
        session = LssSession(bus, args.timeout / 1000, say)
        text, value = _service(args, session)
    except LssError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (can.CanError, GatewaylabError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        bus.shutdown()
    print(json.dumps({"service": args.lss_command, "result": value}) if args.json else text)
    if args.lss_command in ("switch-selective", "fastscan") and not value:
        return 1
    return 0


_DESCRIPTION = """\
Run one CiA 305 LSS master service on a bus of a running rig. TARGET is the bus endpoint that
`gatewaylab run` printed (unix:PATH or tcp:127.0.0.1:PORT) or its ready file (with --bus).
Addresses and ids are hex (0x..) or decimal. Slaves keep their LSS state between runs. A drive
that has a node-ID serves LSS only in NMT state Stopped (IDX guide 3.5); unconfigured ones always.

example (give the unconfigured drive of the default rig node-ID 4):
  gatewaylab lss ready.json fastscan --node-id 4 --store --explain
  gatewaylab lss ready.json switch-global waiting
"""


def add_subcommand(subparsers: Any) -> None:
    """Add ``lss`` with one sub-command per CiA 305 service to the gatewaylab CLI."""
    lss = subparsers.add_parser("lss", help="LSS master services (CiA 305) on a bus of a running rig",
                                description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    lss.add_argument("target", metavar="TARGET", help="bus endpoint or ready file")

    def options(p: argparse.ArgumentParser, top: bool) -> None:
        # accepted before and after SERVICE; a service parser only overrides what was given to it
        def default(value: Any) -> Any:
            return value if top else argparse.SUPPRESS
        p.add_argument("--bus", default=default("can0"), help="bus name in the ready file (default can0)")
        p.add_argument("--timeout", type=_ranged("timeout", 1, 60_000), default=default(100), metavar="MS",
                       help="answer timeout per request in ms (default 100)")
        p.add_argument("--explain", action="store_true", default=default(False),
                       help="print every frame with its meaning")
        p.add_argument("--json", action="store_true", default=default(False),
                       help="print the result as one JSON object")

    options(lss, True)
    sub = lss.add_subparsers(dest="lss_command", required=True, metavar="SERVICE")
    add_parser = sub.add_parser

    def service(name: str, **kwargs: Any) -> argparse.ArgumentParser:
        p: argparse.ArgumentParser = add_parser(name, **kwargs)
        options(p, False)
        return p

    sub.add_parser = service

    p = sub.add_parser("switch-global", help="switch state global: every slave to waiting or configuration")
    p.add_argument("state", choices=("waiting", "configuration"))
    p = sub.add_parser("switch-selective", help="switch state selective: the slave with this address to "
                       "configuration state")
    for part in _PARTS:
        p.add_argument(part, type=_u32, metavar=part.upper())
    p = sub.add_parser("set-node-id", help="configure node-ID of the slave in configuration state")
    p.add_argument("node_id", type=_node_id, metavar="NODE_ID", help="1..127, or 0xFF = unconfigured")
    p = sub.add_parser("set-bit-timing", help="configure bit timing (CiA 305 table index)")
    p.add_argument("index", type=_ranged("table index", 0, 9), metavar="INDEX",
                   help="0=1M 1=800k 2=500k 3=250k 4=125k 6=50k 7=20k 8=10k")
    p = sub.add_parser("activate-bit-timing", help="activate bit timing in every slave after a delay")
    p.add_argument("delay_ms", type=_ranged("delay", 0, 0xFFFF), metavar="DELAY_MS")
    sub.add_parser("store", help="store the configuration of the slave in configuration state")
    p = sub.add_parser("inquire", help="inquire the identity parts or node-ID of the slave in configuration state")
    p.add_argument("what", choices=("all", *_INQUIRE))
    p = sub.add_parser("identify", help="identify remote slaves whose address is in the ranges")
    for name in ("vendor", "product", "revision_low", "revision_high", "serial_low", "serial_high"):
        p.add_argument(name, type=_u32, metavar=name.upper())
    sub.add_parser("identify-unconfigured", help="count the slaves without a node-ID")
    p = sub.add_parser("fastscan", help="find one unconfigured slave's address by bisection (selects it)")
    p.add_argument("--node-id", type=_ranged("node-ID", 1, 127), default=None,
                   help="then give it this node-ID")
    p.add_argument("--store", action="store_true", help="then store the configuration (with --node-id)")
    lss.set_defaults(func=cmd_lss)

