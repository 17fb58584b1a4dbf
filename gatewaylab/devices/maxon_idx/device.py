"""The emulated maxon IDX: a CiA 402 drive on the CAN bus that also serves the USB command protocol.

The drive (:class:`gatewaylab.devices.canopen_drive.device.Drive`) owns the object dictionary; the USB side
reads and writes it locally for node id 0 or the drive's own node id (guide chapter 5) and
forwards everything else to the bus through :class:`~.gateway.CanGateway`. Each connected host
(pseudo-terminal, TCP connection) gets its own :class:`~.protocol.IdxSlave`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.canopen.nmt import NmtCommand
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import Clock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.maxon_idx.commands import MAX_SEGMENT
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode
from gatewaylab.devices.maxon_idx.gateway import CanGateway, SdoClientLike
from gatewaylab.devices.maxon_idx.protocol import IdxSlave

__all__ = ["USB_FRAME_TIMEOUT", "IdxDevice", "NodeObjects"]


#: USB frame timeout object (guide 2.2.6, table 2-4), UNSIGNED16 in ms.
USB_FRAME_TIMEOUT = 0x2006


class NodeObjects:
    """:class:`~.protocol.ObjectAccess` on a :class:`Node`: exactly the checks an SDO access gets."""

    def __init__(self, node: Node) -> None:
        self.node = node

    def read(self, index: int, subindex: int) -> bytes:
        """Read an object of the drive's dictionary (SDO rules and abort codes)."""
        return self.node.read(index, subindex)

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Write an object of the drive's dictionary (SDO rules and abort codes)."""
        self.node.write(index, subindex, data)

    def value_size(self, index: int, subindex: int) -> int | None:
        """The object's fixed size in bytes, None for variable-length objects."""
        return self.node.od.entry(index, subindex).size

    def check_write(self, index: int, subindex: int) -> None:
        """Refuse a segmented write to a read-only object before any data is sent."""
        if not self.node.od.entry(index, subindex).access.writable:
            raise IdxRemoteError(SdoAbortCode.READ_ONLY, f"0x{index:04X}:{subindex:02X} is read only")


def _default_sdo_client(clock: Clock, send: Callable[..., None], timeout: float) -> SdoClientLike:
    from gatewaylab.canopen.sdo_client import SdoClient

    client: SdoClientLike = SdoClient(clock, send, timeout=timeout)
    return client


class IdxDevice:
    """One IDX: drive + USB command protocol + USB-to-CAN gateway."""

    def __init__(self, clock: Clock, bus: VirtualBus, node_id: int | None, serial: int, name: str = "idx",
                 *, store_path: Path | None = None, sdo_timeout: float = 0.5,
                 segment_size: int = MAX_SEGMENT, sdo: SdoClientLike | None = None) -> None:
        self.clock = clock
        self.name = name
        self.drive = Drive(clock, bus, node_id, serial, name, store_path)
        self.node = self.drive.node
        self.segment_size = segment_size
        self.sdo = sdo if sdo is not None else _default_sdo_client(clock, self.node.send, sdo_timeout)
        self.gateway = CanGateway(clock, self.node.send, self.sdo, on_own_nmt=self._own_nmt,
                                  own_node_id=lambda: self.node.node_id, sdo_timeout=sdo_timeout)
        self.node.add_frame_listener(self.gateway.on_frame)
        self.objects = NodeObjects(self.node)
        self.channels: list[IdxSlave] = []

    def _own_nmt(self, command: int) -> None:
        self.node.nmt_command(NmtCommand(command))

    def frame_timeout(self) -> float | None:
        """0x2006 in seconds (0 = no timeout); read at every frame start."""
        ms = int(self.node.get(USB_FRAME_TIMEOUT, 0))
        return ms / 1000.0 if ms else None

    def open_channel(self, send: Callable[[bytes], None]) -> IdxSlave:
        """A USB command channel whose replies go to ``send`` (one per connected host)."""
        slave = IdxSlave(self.clock, self.objects, self.gateway, lambda: self.node.node_id, send,
                         frame_timeout=self.frame_timeout, segment_size=self.segment_size)
        self.channels.append(slave)
        return slave

    def start(self) -> None:
        """Power on the drive behind the USB side."""
        self.drive.start()

    def stop(self) -> None:
        """Close every host channel, then power the drive off."""
        for channel in self.channels:
            channel.close()
        self.drive.stop()
