"""What a participant may offer other participants, declared as Protocols (faults and the segment find
capabilities by these, never by probing attributes).

A device satisfies a capability by having its members (structural typing: no base class, no registration);
``isinstance(p, CanChannels)`` and friends (``runtime_checkable``) check that the members exist, and the
helpers below (:func:`ethercat_devices`, :func:`node_of`, :func:`drive_of`, :func:`segment_of`) also check the
types that a Protocol's ``isinstance`` cannot. What each fault needs (docs/faults.md):

* :class:`CanChannels` -- its CAN controllers by channel name (an EtherCAT gateway: ``mcan0``.., ``can``);
* :class:`HasNode` -- a CANopen node (one channel, ``can``; found by node-ID on its bus);
* :class:`CanopenDrive` (the participant is the drive) or :class:`HasDrive` (it has one) -- power cycle and
  CiA 402 drive faults;
* :class:`EthercatDevice` -- joins the rig's ``[ethercat]`` segment; :class:`HasSegment` -- owns that segment;
* :class:`UsbPluggable` -- a USB port whose cable can be pulled and plugged back in.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

from gatewaylab.bus.controller import Controller
from gatewaylab.canopen.cia402 import PdsState
from gatewaylab.canopen.node import Node
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave

__all__ = [
    "CanChannels",
    "CanopenDrive",
    "EthercatDevice",
    "HasDrive",
    "HasNode",
    "HasSegment",
    "UsbPluggable",
    "can_channels",
    "drive_of",
    "ethercat_devices",
    "node_of",
    "segment_of",
]


@runtime_checkable
class EthercatDevice(Protocol):
    """What a device participant offers the segment (ECAN-Lite and esd CAN-EtherCAT do the same)."""

    name: str
    is_ethercat: bool

    @property
    def slave(self) -> Slave:
        """The device's EtherCAT slave: the segment's view of it."""
        ...


@runtime_checkable
class HasSegment(Protocol):
    """The participant that owns the rig's EtherCAT segment (the ``[ethercat]`` section)."""

    @property
    def segment(self) -> Segment:
        """The line of EtherCAT slaves, position 0 first."""
        ...


@runtime_checkable
class CanChannels(Protocol):
    """A device with one or more CAN controllers, listed by channel name (fault injection picks one)."""

    def can_channels(self) -> Mapping[str, Controller]:
        """The CAN controller of each channel that is attached now."""
        ...


@runtime_checkable
class HasNode(Protocol):
    """A device that is one CANopen node (its controller is the channel ``can``)."""

    @property
    def node(self) -> Node:
        """The device's CANopen node: node-ID, bus, controller, dictionary."""
        ...


@runtime_checkable
class CanopenDrive(Protocol):
    """What fault injection does to a CiA 402 drive: switch it off and on, put it in Fault."""

    @property
    def running(self) -> bool:
        """Switched on: its CANopen node (or the protocol that hosts it) runs."""
        ...

    @property
    def state(self) -> PdsState:
        """Its CiA 402 power drive system state."""
        ...

    def start(self) -> None:
        """Power on: boot-up message, dictionary at its power-on values."""
        ...

    def stop(self) -> None:
        """Power off: the drive leaves the bus."""
        ...

    def fault(self, error_code: int, error_register: int, data: bytes = b"") -> None:
        """A drive fault: EMCY with ``error_code``, 0x603F, the Fault state."""
        ...


@runtime_checkable
class HasDrive(Protocol):
    """A device that contains a CiA 402 drive (the maxon IDX: a drive behind a USB port)."""

    @property
    def drive(self) -> CanopenDrive:
        """The drive inside the device."""
        ...


@runtime_checkable
class UsbPluggable(Protocol):
    """A device with a USB port whose cable fault injection can pull (the maxon IDX)."""

    def usb_unplug(self) -> None:
        """The cable is pulled: open host ports fail, new ones are refused."""
        ...

    def usb_replug(self) -> None:
        """The cable is back: the port enumerates again."""
        ...

    def ready_info(self) -> dict[str, Any]:
        """The port's endpoints (a pty gets a new path at replug)."""
        ...


def ethercat_devices(participants: Sequence[object]) -> list[EthercatDevice]:
    """The participants that join a segment (``is_ethercat`` and a ``slave``), in rig-file order."""
    return [p for p in participants
            if isinstance(p, EthercatDevice) and p.is_ethercat and isinstance(p.slave, Slave)]


def segment_of(participants: Sequence[object]) -> Segment | None:
    """The rig's EtherCAT segment (its ``[ethercat]`` participant), or None when it has none."""
    for p in participants:
        if isinstance(p, HasSegment) and isinstance(p.segment, Segment):
            return p.segment
    return None


def node_of(participant: object) -> Node | None:
    """The participant's CANopen node (:class:`HasNode`), or None."""
    if isinstance(participant, HasNode) and isinstance(participant.node, Node):
        return participant.node
    return None


def drive_of(participant: object) -> CanopenDrive | None:
    """The CiA 402 drive the participant is (:class:`CanopenDrive`) or has (:class:`HasDrive`), or None."""
    if isinstance(participant, CanopenDrive):
        return participant
    if isinstance(participant, HasDrive) and isinstance(participant.drive, CanopenDrive):
        return participant.drive
    return None


def can_channels(participant: object) -> dict[str, Controller]:
    """The participant's CAN controllers by channel name: its :class:`CanChannels`, or its node's
    controller as ``can`` (:class:`HasNode`); empty when it has no CAN side."""
    if isinstance(participant, CanChannels):
        return dict(participant.can_channels())
    node = node_of(participant)
    return {"can": node.controller} if node is not None else {}
