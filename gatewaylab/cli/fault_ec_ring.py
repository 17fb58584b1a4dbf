"""``gatewaylab fault`` verbs of ports, cables and hot-connect groups (rig/faults_ec_ring.py): ``ec-port-open``,
``ec-ring-break`` / ``ec-ring-heal``, ``ec-hot-unplug`` / ``ec-hot-plug``."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["add_verbs"]


def _seconds(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"a number of seconds > 0, not {text}")
    return value


def _port(text: str) -> int:
    value = int(text, 0)
    if not 0 <= value <= 3:
        raise argparse.ArgumentTypeError(f"an ESC port 0..3, not {text}")
    return value


def add_verbs(fault: Callable[[str, str, str], argparse.ArgumentParser]) -> None:
    """Add the verbs to ``gatewaylab fault``."""
    p = fault("ec-port-open", "open a port of an EtherCAT device: the cable there loses its link (the devices "
                              "behind it vanish from a line; a redundant master reaches them the other way)",
              "gatewaylab fault ready.json ec-port-open io1 1 --seconds 2")
    p.add_argument("device", metavar="DEVICE")
    p.add_argument("port", metavar="PORT", type=_port, help="0: towards the master, 1: away from it")
    p.add_argument("--seconds", type=_seconds, help="close it again after this long (default: on ec-clear)")
    p.set_defaults(request=lambda a: {"device": a.device, "port": a.port,
                                      **({} if a.seconds is None else {"seconds": a.seconds})})
    p = fault("ec-ring-break", "break a redundant ring after AFTER-DEVICE (the devices after it answer through "
                               "the secondary interface)", "gatewaylab fault ready.json ec-ring-break io1")
    p.add_argument("after_device", metavar="AFTER-DEVICE")
    p.set_defaults(request=lambda a: {"after_device": a.after_device})
    p = fault("ec-ring-heal", "mend every break of the redundant ring", "gatewaylab fault ready.json ec-ring-heal")
    p.set_defaults(request=lambda a: {})
    p = fault("ec-hot-unplug", "unplug the hot-connect group HEAD heads ([ethercat] hot_connect): the devices after "
                               "it stay in the line", "gatewaylab fault ready.json ec-hot-unplug io2")
    p.add_argument("head", metavar="HEAD")
    p.set_defaults(request=lambda a: {"head": a.head})
    p = fault("ec-hot-plug", "plug the hot-connect group of HEAD back in (its devices power on in INIT)",
              "gatewaylab fault ready.json ec-hot-plug io2")
    p.add_argument("head", metavar="HEAD")
    p.set_defaults(request=lambda a: {"head": a.head})
