"""The bus class that ``interface="virtual"`` opens during `make conformance` (see gatewaylab_conformance.py)."""

from __future__ import annotations

from typing import Any

import can

from gatewaylab.bus.transport.plugin import GatewaylabBus


class VirtualOnRig(GatewaylabBus):
    """What ``can.Bus(interface="virtual", channel=NAME)`` opens during the conformance run."""

    endpoints: list[str] = []
    assigned: dict[Any, str] = {}

    def __init__(self, channel: Any = None, **kwargs: Any) -> None:
        for virtual_only in ("preserve_timestamps", "protocol", "rx_queue_size"):
            kwargs.pop(virtual_only, None)
        super().__init__(channel, **kwargs)

    def _endpoint(self, channel: Any) -> str:
        key = channel if isinstance(channel, (str, int)) or channel is None else repr(channel)
        endpoint = self.assigned.get(key)
        if endpoint is None:
            free = [e for e in self.endpoints if e not in self.assigned.values()]
            if not free:
                raise can.CanInitializationError(f"the conformance rig has no bus left for channel {channel!r}")
            endpoint = self.assigned[key] = free[0]
        return endpoint
