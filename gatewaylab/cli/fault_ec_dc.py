"""``gatewaylab fault`` verbs of distributed clocks (rig/faults_ec_dc.py): ``ec-dc-drift``, ``ec-dc-jump``."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["add_verbs"]


def _ppm(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of ppm: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"a finite number of ppm, not {text}")
    return value


def _ns(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number of nanoseconds: {text!r}") from None


def add_verbs(fault: Callable[[str, str, str], argparse.ArgumentParser]) -> None:
    """Add the verbs to ``gatewaylab fault``."""
    p = fault("ec-dc-drift", "an EtherCAT device's local clock runs PPM fast (negative: slow) until ec-clear; "
                             "the master's drift compensation must follow (0x092C)",
              "gatewaylab fault ready.json ec-dc-drift io1 80")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("ppm", metavar="PPM", type=_ppm)
    p.set_defaults(request=lambda a: {"device": a.device, "ppm": a.ppm})
    p = fault("ec-dc-jump", "an EtherCAT device's local time jumps by NS once (a master's DC re-initialisation "
                            "fixes it)", "gatewaylab fault ready.json ec-dc-jump io1 -- -5000000")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("ns", metavar="NS", type=_ns, help="nanoseconds, may be negative (after --)")
    p.set_defaults(request=lambda a: {"device": a.device, "ns": a.ns})
