"""``gatewaylab fault READY-FILE FAULT ARGS...``: inject a fault into a running rig (docs/faults.md).

The command sends one JSON request to the rig's control endpoint (the ready file's ``"control"``)
and prints the answer. Exit 0: done; 1: the rig refused it (unknown device, no such part, a rig
that is gone); 2: the command line is wrong.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gatewaylab.cli import fault_ec_dc, fault_ec_frames, fault_ec_ring, fault_ec_slave
from gatewaylab.common.ask import ask, endpoint_address
from gatewaylab.common.endpoint import EndpointKind, parse_endpoint
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.rig.faults import DRIVE_FAULTS

__all__ = ["FAULT_FAMILIES", "FaultCliError", "add_subcommand", "build_request", "cmd_fault", "send_request"]


_DESCRIPTION = """\
Inject a fault into a running rig through its control endpoint (listed in the ready file of
`gatewaylab run --ready-file`). Targets are device names (as in the rig file, or the default
names the ready file lists: drive2, drive2@can1 when drive 2 is on two buses) or, with --bus,
CANopen node-IDs. Numbers may be decimal or 0x-hex.
"""

_EXAMPLES = """\
examples:
  gatewaylab fault ready.json bus-errors can0 0.5            # error frames on can0 for 0.5 s
  gatewaylab fault ready.json stuck-dominant can0 0.2         # no frame completes for 0.2 s
  gatewaylab fault ready.json drop can0 0x182 -n 3            # the next 3 frames of 0x182 vanish
  gatewaylab fault ready.json corrupt can0 0x702              # the next 0x702 frame: CRC error
  gatewaylab fault ready.json error-passive axis2             # drive axis2's controller: TEC 128
  gatewaylab fault ready.json bus-off 2 --bus can0            # node 2 on can0 goes bus-off
  gatewaylab fault ready.json can-unplug axis2                # pull axis2's CAN connector
  gatewaylab fault ready.json power-cycle axis2 --off 1.5     # off for 1.5 s, then boot-up
  gatewaylab fault ready.json drive-fault axis2 over-current  # EMCY 0x2310, CiA 402 Fault
  gatewaylab fault ready.json ethercat-unplug io1             # io1 and the devices behind it go silent
  gatewaylab fault ready.json usb-unplug idx1                 # the IDX's USB port drops its host
"""


#: the verbs of each family of EtherCAT faults: ``add_verbs(fault)`` gets the factory of a verb's parser
#: (``fault(name, help, example) -> ArgumentParser``) and sets ``request=`` on each verb it adds
FAULT_FAMILIES: tuple[Callable[[Callable[[str, str, str], argparse.ArgumentParser]], None], ...] = (
    fault_ec_frames.add_verbs,
    fault_ec_dc.add_verbs,
    fault_ec_slave.add_verbs,
    fault_ec_ring.add_verbs,
)

#: answer fields printed in hex (the --json output keeps JSON numbers)
_HEX = ("can_id", "error_code", "al_status")


class FaultCliError(GatewaylabError):
    """The rig refused the fault or cannot be reached (exit 1)."""


def _number(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def _can_id(text: str) -> int:
    value = _number(text)
    if not 0 <= value <= 0x1FFFFFFF:
        raise argparse.ArgumentTypeError(f"CAN id {text} is out of range (0..0x7FF, or 0..0x1FFFFFFF extended)")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"seconds must be >= 0, got {text}")
    return value


def _target(args: argparse.Namespace) -> dict[str, Any]:
    """A device name, or a node-ID when --bus is given and TARGET is a number."""
    out: dict[str, Any] = {}
    if args.bus is not None:
        out["bus"] = args.bus
        try:
            out["node"] = int(args.target, 0)
            return out
        except ValueError:
            pass
    out["device"] = args.target
    if getattr(args, "channel", None) is not None:
        out["channel"] = args.channel
    return out


def build_request(args: argparse.Namespace) -> dict[str, Any]:
    """The control request for parsed arguments (docs/faults.md lists the same fields)."""
    name = args.fault
    req: dict[str, Any] = {"fault": name}
    builder = getattr(args, "request", None)
    if builder is not None:         # a verb that builds its own request (the EtherCAT families)
        req.update(builder(args))
        return req
    if name in ("bus-errors", "stuck-dominant"):
        req.update(bus=args.bus_name, duration=args.seconds)
        if name == "bus-errors" and args.every != 1:
            req["every"] = args.every
    elif name in ("drop", "corrupt"):
        req.update(bus=args.bus_name, can_id=args.can_id, count=args.count)
    elif name in ("error-passive", "bus-off", "can-unplug", "can-replug"):
        req.update(_target(args))
    elif name == "power-cycle":
        req.update(_target(args), off=args.off)
    elif name == "drive-fault":
        req.update(_target(args), kind=args.kind)
        if args.code is not None:
            req["code"] = args.code
    else:
        req["device"] = args.device
    return req


def send_request(ready_file: str, req: dict[str, Any], timeout: float = 10.0) -> dict[str, Any]:
    """Send one request to the control endpoint named in ``ready_file``; the decoded answer."""
    try:
        info = json.loads(Path(ready_file).read_text())
        endpoint = parse_endpoint(str(info["control"]), bare_path=EndpointKind.UNIX)
    except FileNotFoundError:
        raise ConfigError(f"{ready_file}: no such ready file (is the rig running? `gatewaylab run --ready-file "
                          f"{ready_file}` writes it)") from None
    except OSError as exc:              # docs/cli.md: a file named that cannot be used is exit 2
        raise ConfigError(f"cannot read ready file {ready_file}: {exc.strerror or exc}") from None
    except (ValueError, KeyError, TypeError):
        raise ConfigError(f"{ready_file}: not the ready file of a rig with a control endpoint") from None
    try:
        buf = ask(endpoint_address(endpoint), req, timeout)
    except OSError as exc:
        raise FaultCliError(f"cannot reach the rig at {endpoint}: {exc.strerror or exc} (is it running?)") from None
    try:
        answer: dict[str, Any] = json.loads(buf)
    except ValueError:
        raise FaultCliError(f"the rig at {endpoint} gave no answer") from None
    return answer


def cmd_fault(args: argparse.Namespace) -> int:
    """``gatewaylab fault``: send the request, print the rig's answer (``--json``: as JSON); exit 0 when done."""
    answer = send_request(args.ready_file, build_request(args))
    if not answer.get("ok"):
        raise FaultCliError(f"fault refused: {answer.get('error', answer)}")
    if args.json:
        print(json.dumps(answer))
    else:
        details = ", ".join(f"{k}=0x{v:X}" if k in _HEX and isinstance(v, int) else f"{k}={v}"
                            for k, v in answer.items() if k not in ("ok", "fault"))
        print(f"{answer.get('fault')}: {details}")
    sys.stdout.flush()
    return 0


def add_subcommand(subparsers: Any) -> None:
    """Add ``fault`` with one sub-command per fault to the gatewaylab CLI."""
    top = subparsers.add_parser("fault", help="inject a fault into a running rig (bus errors, unplug, ...)",
                                description=_DESCRIPTION, epilog=_EXAMPLES,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    top.add_argument("ready_file", metavar="READY-FILE", help="the ready file of `gatewaylab run --ready-file`")
    top.add_argument("--json", action="store_true", help="print the rig's answer as one JSON object")
    top.set_defaults(func=cmd_fault)
    sub = top.add_subparsers(dest="fault", required=True, metavar="FAULT")

    def fault(name: str, help: str, example: str) -> argparse.ArgumentParser:
        """A verb's parser; a verb whose request is not built by :func:`build_request` sets
        ``request=FUNCTION(args) -> dict`` as a default."""
        p: argparse.ArgumentParser = sub.add_parser(
            name, help=help, description=help, epilog=f"example:\n  {example}",
            formatter_class=argparse.RawDescriptionHelpFormatter)
        p.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                       help="print the rig's answer as one JSON object")
        return p

    def target(p: argparse.ArgumentParser, channel: bool = True) -> None:
        p.add_argument("target", metavar="TARGET", help="device name, or a node-ID with --bus")
        p.add_argument("--bus", help="the bus of a node-ID TARGET")
        if channel:
            p.add_argument("--channel", help="which CAN channel of a device with several (a gateway's)")

    p = fault("bus-errors", "error frames on a bus for a time (one frame in EVERY ends in a CRC error)",
              "gatewaylab fault ready.json bus-errors can0 0.5 --every 4")
    p.add_argument("bus_name", metavar="BUS")
    p.add_argument("seconds", metavar="SECONDS", type=_seconds)
    p.add_argument("--every", type=_number, default=1, help="destroy one frame in EVERY (default 1: all)")
    p = fault("stuck-dominant", "hold a bus dominant for a time: transmitters go bus-off, recovery after",
              "gatewaylab fault ready.json stuck-dominant can0 0.2")
    p.add_argument("bus_name", metavar="BUS")
    p.add_argument("seconds", metavar="SECONDS", type=_seconds)
    for name, what in (("drop", "vanish (the sender sees success)"), ("corrupt", "end in a CRC error (retransmitted)")):
        p = fault(name, f"the next N frames of a CAN id {what}", f"gatewaylab fault ready.json {name} can0 0x182 -n 3")
        p.add_argument("bus_name", metavar="BUS")
        p.add_argument("can_id", metavar="CAN-ID", type=_can_id)
        p.add_argument("-n", "--count", type=_number, default=1, help="how many frames (default 1)")
    for name, help, example in (
            ("error-passive", "a device's CAN controller to error-passive (TEC 128)",
             "gatewaylab fault ready.json error-passive axis2"),
            ("bus-off", "a device's CAN controller to bus-off (recovers after 128 x 11 recessive bits)",
             "gatewaylab fault ready.json bus-off 2 --bus can0"),
            ("can-unplug", "pull a device's CAN connector (a drive, an IDX, a gateway's channel)",
             "gatewaylab fault ready.json can-unplug axis2"),
            ("can-replug", "plug a device's CAN connector back in",
             "gatewaylab fault ready.json can-replug axis2")):
        target(fault(name, help, example))
    p = fault("power-cycle", "switch a drive off and on: boot-up, volatile dictionary values lost, stored kept",
              "gatewaylab fault ready.json power-cycle axis2 --off 1.5")
    target(p, channel=False)
    p.add_argument("--off", type=_seconds, default=1.0, metavar="SECONDS", help="time switched off (default 1)")
    p = fault("drive-fault", "a CiA 402 drive fault: EMCY with its error code, Fault state",
              "gatewaylab fault ready.json drive-fault axis2 following-error")
    target(p, channel=False)
    p.add_argument("kind", choices=tuple(DRIVE_FAULTS), help="following-error (0x8611) or over-current (0x2310)")
    p.add_argument("--code", type=_number, help="another EMCY error code (0x1000..0xFFFF) for the same reaction")
    for name, help in (("ethercat-unplug", "pull an EtherCAT device out of its segment (it and those behind: silent)"),
                       ("ethercat-replug", "plug an EtherCAT device back in (it powers on in INIT)"),
                       ("usb-unplug", "pull a device's USB cable (its host port fails, new hosts are refused)"),
                       ("usb-replug", "plug the USB cable back in (prints the port's endpoints)")):
        p = fault(name, help, f"gatewaylab fault ready.json {name} {'io1' if 'ethercat' in name else 'idx1'}")
        p.add_argument("device", metavar="DEVICE")
    for add_verbs in FAULT_FAMILIES:
        add_verbs(fault)
    p = fault("ec-clear", "end every active EtherCAT fault (of DEVICE only, when given)",
              "gatewaylab fault ready.json ec-clear")
    p.add_argument("device", metavar="DEVICE", nargs="?")
    p.set_defaults(request=lambda a: {} if a.device is None else {"device": a.device})
