"""The ``gatewaylab fault`` verbs of one slave's faults: AL state machine, mailbox, EEPROM (docs/faults.md).

``ec-al-error``, ``ec-drop-state``, ``ec-sdo-abort``, ``ec-sdo-silent``, ``ec-foe-error``,
``ec-mailbox-lose``, ``ec-emcy``, ``ec-eeprom``; each builds the control request of the same name
(``gatewaylab/rig/faults_ec_slave.py``).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

__all__ = ["add_verbs"]


def _number(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def _count(text: str) -> int:
    value = _number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"seconds must be > 0, got {text}")
    return value


def _optional(args: argparse.Namespace, *names: str) -> dict[str, Any]:
    return {n: getattr(args, n) for n in names if getattr(args, n) is not None}


def add_verbs(fault: Callable[[str, str, str], argparse.ArgumentParser]) -> None:
    """Add the verbs (``fault(name, help, example)`` makes a verb's parser)."""
    p = fault("ec-al-error", "a slave refuses the next AL transition (or only --on TRANSITION) with an AL status "
              "code; the error flag stays until the master acknowledges",
              "gatewaylab fault ready.json ec-al-error io1 0x001D --on PS")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("code", metavar="CODE", type=_number, help="AL status code (e.g. 0x001D, 0x0035)")
    p.add_argument("--on", metavar="TRANSITION",
                   help="only this transition: IP, PS, SO, OS, SP ... or PREOP-SAFEOP (ETG.1000.6 names)")
    p.set_defaults(request=lambda a: {"device": a.device, "code": a.code, **_optional(a, "on")})

    p = fault("ec-drop-state", "a slave leaves its state by itself: SAFEOP/PREOP + error flag + code; INIT "
              "without --code is a power glitch (the ESC resets, station address lost)",
              "gatewaylab fault ready.json ec-drop-state io1 SAFEOP")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("state", metavar="STATE", choices=("INIT", "PREOP", "SAFEOP", "init", "preop", "safeop"))
    p.add_argument("--code", type=_number, help="AL status code (default 0x001B for SAFEOP, 0x0001 for PREOP)")
    p.set_defaults(request=lambda a: {"device": a.device, "state": a.state.upper(), **_optional(a, "code")})

    p = fault("ec-sdo-abort", "the next CoE SDO request (to --index only) is answered with an abort code, or "
              "the K-th segment request of its transfer (--segment K)",
              "gatewaylab fault ready.json ec-sdo-abort io1 0x06020000 --index 0x2000")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("code", metavar="CODE", type=_number, help="SDO abort code (CiA 301 / ETG.1000.6)")
    p.add_argument("--index", type=_number, help="only a request to this object index")
    p.add_argument("--segment", type=_count, metavar="K", help="abort at the K-th segment (1: the first)")
    p.set_defaults(request=lambda a: {"device": a.device, "code": a.code, **_optional(a, "index", "segment")})

    p = fault("ec-sdo-silent", "the next N CoE SDO requests get no answer at all (the master's SDO timeout)",
              "gatewaylab fault ready.json ec-sdo-silent io1 -n 2")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("-n", type=_count, default=1, help="how many requests (default 1)")
    p.set_defaults(request=lambda a: {"device": a.device, "n": a.n})

    p = fault("ec-foe-error", "the next FoE transfer fails at data packet K with an FoE error code",
              "gatewaylab fault ready.json ec-foe-error io1 0x8008 --packet 2")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("code", metavar="CODE", type=_number, help="FoE error code (ETG.1000.6, e.g. 0x8001 not found)")
    p.add_argument("--packet", type=_count, required=True, metavar="K", help="the data packet that fails (1: first)")
    p.set_defaults(request=lambda a: {"device": a.device, "code": a.code, "packet": a.packet})

    p = fault("ec-mailbox-lose", "the next mailbox reply is lost once: the master's repeat request (SM1 0x0806 "
              "bit 1) gets it back", "gatewaylab fault ready.json ec-mailbox-lose io1")
    p.add_argument("device", metavar="DEVICE")
    p.set_defaults(request=lambda a: {"device": a.device})

    p = fault("ec-emcy", "the slave sends a CoE emergency (error code, error register, 5 data bytes)",
              "gatewaylab fault ready.json ec-emcy io1 0x8110 --register 0x11")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("code", metavar="CODE", type=_number, help="emergency error code (16 bits)")
    p.add_argument("--register", type=_number, default=0, help="error register (0x1001), default 0")
    p.add_argument("--data", default="", metavar="HEX", help="up to 5 data bytes as hex (default zeros)")
    p.set_defaults(request=lambda a: {"device": a.device, "code": a.code, "register": a.register,
                                      **({"data": a.data} if a.data else {})})

    p = fault("ec-eeprom", "the slave's EEPROM: busy (SII busy for --seconds), checksum (bad SII checksum, "
              "0x0502 bit 11), stuck (a read never completes), product=0xNNNN (a wrong device)",
              "gatewaylab fault ready.json ec-eeprom io1 product=0x1234")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("kind", metavar="busy|checksum|stuck|product=0xNNNN")
    p.add_argument("--seconds", type=_seconds, help="ends by itself after this long (busy: default 1)")
    p.set_defaults(request=lambda a: {"device": a.device, "kind": a.kind, **_optional(a, "seconds")})
