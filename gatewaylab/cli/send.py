"""``gatewaylab send ENDPOINT FRAME``: one frame onto a rig's bus, in can-utils' ``cansend`` syntax.

``123#DEADBEEF`` (11-bit id, 3 hex digits), ``12345678#00`` (29-bit, 8 digits), ``123#R`` /
``123#R5`` (remote frame, length), ``123##1AABB`` (CAN FD: flags nibble, 1 = bit rate switch,
2 = error state indicator). The parser is :func:`~gatewaylab.bus.candump.parse_cansend`; this
module opens the bus, sends, and waits until the frame was acknowledged (its own echo), so the exit
code says whether it reached the bus: 0 sent, 1 not acknowledged / bus-off / rig gone, 2 usage.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import can

from gatewaylab.bus.candump import CandumpSyntaxError, parse_cansend
from gatewaylab.cli.target import USAGE, Unreachable, bus_target, open_endpoint
from gatewaylab.common.endpoint import EndpointError

__all__ = ["add_subcommand", "cmd_send"]


_DESCRIPTION = """\
Send one frame to a bus of a running rig, written as for can-utils' cansend:

  123#DEADBEEF       11-bit id 0x123, 4 data bytes (3 hex digits: 11-bit id)
  12345678#11.22     29-bit id (8 hex digits), bytes optionally separated by '.'
  123#R  123#R5      remote frame, with optional length 0..8
  123##1AABBCC       CAN FD frame; the nibble after '##' holds flags: 1 BRS, 2 ESI

ENDPOINT is what `gatewaylab run` printed (unix:PATH, tcp:HOST:PORT) or its ready file. The command
waits until the frame was acknowledged by another node (exit 0); exit 1 when nobody acknowledged it
within --timeout (a lone client: run the rig with --acker) or the rig is gone; exit 2 on a usage
error (bad frame, no such ready file).

examples:
  gatewaylab send ready.json 000#0100           # NMT start all nodes
  gatewaylab send unix:/tmp/gl/can0.sock 602#4018100100000000
"""


def cmd_send(args: argparse.Namespace) -> int:
    """Send the frame; wait for its echo (it left the transmit queue acknowledged)."""
    try:
        frame = parse_cansend(args.frame)
        endpoint = bus_target(args.endpoint, args.bus)
    except (CandumpSyntaxError, EndpointError) as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return USAGE
    try:
        bus = open_endpoint(endpoint, receive_own_messages=True, name="gatewaylab-send", shutdown_timeout=0.5)
    except Unreachable as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 1
    try:
        bus.send(frame.to_message(), timeout=args.timeout)
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            msg = bus.recv(max(0.0, min(0.1, deadline - time.monotonic())))
            if msg is not None and not msg.is_error_frame and not msg.is_rx \
                    and msg.arbitration_id == frame.can_id and msg.is_extended_id == frame.extended:
                return 0
            state = getattr(bus, "controller_state", None)
            if getattr(bus, "tx_errors", 0) or (state is not None and state.name == "BUS_OFF"):
                break
        state = getattr(bus, "controller_state", None)
        how = f" (controller {state.name.lower().replace('_', '-')})" if state is not None else ""
        print(f"gatewaylab: {frame} was not acknowledged within {args.timeout} s{how}: is another node on "
              "the bus? (a lone client: run the rig with --acker)", file=sys.stderr)
        return 1
    except can.CanError as exc:
        print(f"gatewaylab: {exc}", file=sys.stderr)
        return 1
    finally:
        bus.shutdown()


def add_subcommand(subparsers: Any) -> None:
    """Add ``send`` to the gatewaylab CLI."""
    p = subparsers.add_parser("send", help="send one frame (cansend syntax: 123#DEADBEEF)",
                              description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("endpoint", metavar="ENDPOINT", help="bus endpoint (unix:PATH, tcp:HOST:PORT) or ready file")
    p.add_argument("frame", metavar="FRAME", help="the frame in cansend syntax, e.g. 123#DEADBEEF")
    p.add_argument("--bus", default="can0", help="bus name in the ready file (default can0)")
    p.add_argument("--timeout", type=float, default=2.0, metavar="S",
                   help="how long to wait for the acknowledgement (default 2 s)")
    p.set_defaults(func=cmd_send)
