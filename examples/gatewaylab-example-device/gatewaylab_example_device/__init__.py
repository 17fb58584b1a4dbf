"""A CAN echo box: the smallest useful gatewaylab device plugin.

It answers every frame with CAN-ID ``request_id`` by sending the same bytes, reversed, with CAN-ID
``reply_id``, ``delay_ms`` later. Rig file::

    [[device]]
    kind = "example_echo"
    name = "echo1"
    bus = "can0"
    request_id = 0x321
    reply_id = 0x322
    delay_ms = 1.0

Everything a device needs from gatewaylab comes from :mod:`gatewaylab.plugin` (the rig
interface), :mod:`gatewaylab.bus` (frames and controllers) and the rig's clock.
"""

from __future__ import annotations

from typing import Any

from gatewaylab.bus import CanFrame, Controller
from gatewaylab.plugin import DeviceKind, Key, RigContext

#: The section's keys: the rig checks types, ranges and bus names before ``create`` runs.
KEYS: dict[str, Key] = {
    "name": Key(str, required=True),
    "bus": Key(str, "can0", bus=True, help="the name of a [[bus]]"),
    "request_id": Key(int, 0x321, min=0, max=0x7FF, hex=True, help="an 11-bit CAN-ID"),
    "reply_id": Key(int, 0x322, min=0, max=0x7FF, hex=True, help="an 11-bit CAN-ID"),
    "delay_ms": Key(float, 0.0, min=0, max=1000),
}


class EchoBox:
    """The participant: built by :func:`create`, started and stopped by the rig."""

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        self.name: str = cfg["name"]
        self.clock = rig.clock
        self.bus = rig.bus(cfg["bus"])
        self.request_id: int = cfg["request_id"]
        self.reply_id: int = cfg["reply_id"]
        self.delay: float = cfg["delay_ms"] / 1000.0
        self.controller: Controller | None = None
        self.echoed = 0

    def start(self) -> None:
        """Plug into the bus; from now on frames arrive in :meth:`_on_frame` (on the rig's thread)."""
        self.controller = self.bus.attach(self.name, on_frame=self._on_frame)

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        if frame.can_id == self.request_id and not frame.extended and not frame.rtr:
            reply = CanFrame(self.reply_id, bytes(reversed(frame.data)), fd=frame.fd, brs=frame.brs)
            self.clock.call_later(self.delay, self._send, reply)

    def _send(self, frame: CanFrame) -> None:
        if self.controller is not None:
            self.controller.send(frame)
            self.echoed += 1

    def stop(self) -> None:
        """Unplug; the rig calls this once, also when another device failed to start."""
        if self.controller is not None:
            self.bus.detach(self.controller)
            self.controller = None

    def ready_info(self) -> dict[str, Any]:
        """Merged into `gatewaylab run --ready-file`: what a client needs to talk to the device."""
        return {"example_echo": {self.name: {"request_id": self.request_id, "reply_id": self.reply_id}}}


def create(rig: RigContext, cfg: dict[str, Any]) -> EchoBox:
    """The factory: ``cfg`` is already validated against :data:`KEYS` (defaults filled in)."""
    return EchoBox(rig, cfg)


#: What the entry point names: the kind, its factory and its keys.
KIND = DeviceKind("example_echo", create, KEYS, summary="example plugin: a CAN echo box")
