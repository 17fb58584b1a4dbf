"""``gatewaylab fault`` verbs of frames, working counters and the master's link (rig/faults_ec_frames.py):
``ec-lose``, ``ec-corrupt``, ``ec-delay``, ``ec-duplicate``, ``ec-reorder``, ``ec-wkc``, ``ec-outputs-off``,
``ec-link-down`` (docs/faults.md "EtherCAT faults")."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.ethercat.line_faults import parse_command

__all__ = ["add_verbs"]


def _number(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def _command(text: str) -> str:
    try:
        parse_command(text)
    except EtherCATConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text.upper()


def _filters(p: argparse.ArgumentParser, station: bool = True) -> None:
    p.add_argument("--cmd", type=_command, action="append", metavar="CMD",
                   help="only frames with a datagram of this command (APRD, FPWR, LRW, BRD ... or 0..14; repeatable)")
    if station:
        p.add_argument("--station", type=_number, metavar="ADDR",
                       help="only frames with a datagram for this configured station address (FPRD/FPWR/FPRW/FRMW)")
    p.add_argument("--logical", metavar="START:END",
                   help="only frames with a logical datagram (LRD/LWR/LRW) overlapping START..END (END included)")


def _filter_args(a: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if a.cmd:
        out["cmd"] = ",".join(a.cmd)
    if getattr(a, "station", None) is not None:
        out["station"] = a.station
    if a.logical is not None:
        out["logical"] = a.logical
    return out


def _lose(a: argparse.Namespace) -> dict[str, Any]:
    return {"count": a.count, **({"replies": True} if a.replies else {}), **_filter_args(a)}


def _delay(a: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {"us": a.us}
    if a.jitter:
        out["jitter"] = a.jitter
    if a.seconds is not None:
        out["seconds"] = a.seconds
    if a.seed is not None:
        out["seed"] = a.seed
    return out


def _wkc(a: argparse.Namespace) -> dict[str, Any]:
    return {"offset": a.offset, "count": a.count, **_filter_args(a)}


def _outputs_off(a: argparse.Namespace) -> dict[str, Any]:
    return {"device": a.device, **({} if a.seconds is None else {"seconds": a.seconds})}


def add_verbs(fault: Callable[[str, str, str], argparse.ArgumentParser]) -> None:
    """Add this family's verbs to ``gatewaylab fault``."""
    p = fault("ec-lose", "lose the next N EtherCAT frames (both ways, or only the replies), optionally only "
              "those with a datagram matching --cmd/--station/--logical",
              "gatewaylab fault ready.json ec-lose 3 --cmd LRW")
    p.add_argument("count", metavar="N", type=_number)
    p.add_argument("--replies", action="store_true",
                   help="the slaves process the frames (state changes happen), only the replies are lost")
    _filters(p)
    p.set_defaults(request=_lose)
    p = fault("ec-corrupt", "the next N replies come back with a bad FCS: the master's NIC drops them "
              "(the slaves did process them)", "gatewaylab fault ready.json ec-corrupt 2")
    p.add_argument("count", metavar="N", type=_number)
    p.set_defaults(request=lambda a: {"count": a.count})
    p = fault("ec-delay", "delay every reply by US microseconds (+ uniform jitter) for SECONDS or until ec-clear",
              "gatewaylab fault ready.json ec-delay 3000 --jitter 500 --seconds 2")
    p.add_argument("us", metavar="US", type=_float)
    p.add_argument("--jitter", type=_float, default=0.0, metavar="US", help="add 0..US microseconds (uniform)")
    p.add_argument("--seconds", type=_float, metavar="S", help="end by itself after S seconds")
    p.add_argument("--seed", type=_number, help="the jitter generator's seed (default 1: the same jitter every run)")
    p.set_defaults(request=_delay)
    for name, what in (("ec-duplicate", "the next N replies arrive twice (a switch in the path)"),
                       ("ec-reorder", "the next N replies each arrive after the reply that follows them")):
        p = fault(name, what, f"gatewaylab fault ready.json {name} 1")
        p.add_argument("count", metavar="N", type=_number)
        p.set_defaults(request=lambda a: {"count": a.count})
    p = fault("ec-wkc", "add OFFSET to the working counter of the next N matching datagrams (overwrite WKC)",
              "gatewaylab fault ready.json ec-wkc 1 -n 5 --cmd LRW")
    p.add_argument("offset", metavar="OFFSET", type=_number)
    p.add_argument("-n", "--count", type=_number, default=1, help="how many datagrams (default 1)")
    _filters(p, station=False)
    p.set_defaults(request=_wkc)
    p = fault("ec-outputs-off", "a slave's firmware deactivates its output SyncManager (0x0807 bit 0): its "
              "outputs stop counting in the working counter", "gatewaylab fault ready.json ec-outputs-off io1")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("--seconds", type=_float, metavar="S", help="end by itself after S seconds")
    p.set_defaults(request=_outputs_off)
    p = fault("ec-link-down", "the master's link is down for SECONDS: no frame passes either way",
              "gatewaylab fault ready.json ec-link-down 1.5")
    p.add_argument("seconds", metavar="SECONDS", type=_float)
    p.set_defaults(request=lambda a: {"seconds": a.seconds})
