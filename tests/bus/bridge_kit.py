"""A pretend python-can adapter for the bridge tests: an interface (``gatewaylab_flaky``) over
python-can's ``virtual`` bus that can be unplugged and plugged in again, as a USB adapter is, failing
the way drivers fail (CanInitializationError on open, CanOperationError on recv/send)."""

from __future__ import annotations

import threading
from typing import Any

import can
from can.interfaces.virtual import VirtualBus

INTERFACE = "gatewaylab_flaky"


def bridge_rig(interface: str, channel: str, options: str = "") -> str:
    """A rig file: can0 with drive 2 (axis2), bridged to ``interface``/``channel`` (``options``: an inline
    TOML table of more can.Bus arguments, e.g. ``{ hop_limit = 0 }``)."""
    extra = f"\noptions = {options}" if options else ""
    return f"""
clock = "realtime"
[[bus]]
name = "can0"
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
[[bridge]]
bus = "can0"
interface = "{interface}"
channel = "{channel}"{extra}
"""


class Adapter:
    """One pretend adapter: plugged in or not, and events a test waits on (no sleeping)."""

    def __init__(self) -> None:
        self.plugged = True
        self.opened = threading.Event()
        self.failed = threading.Event()
        self.opens = 0


#: channel -> adapter; python-can builds the bus from its name, so the test's adapter is found here
ADAPTERS: dict[str, Adapter] = {}


def register(channel: str) -> Adapter:
    """Make ``gatewaylab_flaky`` a python-can interface in this process (python-can checks names against
    VALID_INTERFACES, frozen at its import from BACKENDS and the can.interface entry points)."""
    can.interfaces.BACKENDS[INTERFACE] = (__name__, "FlakyBus")
    can.util.VALID_INTERFACES = frozenset({*can.util.VALID_INTERFACES, INTERFACE})
    adapter = ADAPTERS[channel] = Adapter()
    return adapter


class FlakyBus(can.BusABC):
    def __init__(self, channel: str, **kwargs: Any) -> None:
        self.adapter = ADAPTERS[channel]
        if not self.adapter.plugged:
            self.adapter.failed.set()
            raise can.CanInitializationError(f"no adapter on {channel} (unplugged)")
        self.inner = VirtualBus(channel=channel)
        self.adapter.opens += 1
        super().__init__(channel=channel)
        self.adapter.opened.set()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self.adapter.plugged:
            self.adapter.failed.set()
            raise can.CanOperationError("the adapter vanished")
        return self.inner._recv_internal(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.adapter.plugged:
            raise can.CanOperationError("the adapter vanished")
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()
