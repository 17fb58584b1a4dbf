"""What a participant may offer other participants, declared as Protocols (issue 22: faults and the segment
find capabilities by these, never by probing attributes)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, cast, runtime_checkable

from gatewaylab.ethercat.slave import Slave


@runtime_checkable
class EthercatDevice(Protocol):
    """What a device participant offers the segment (ECAN-Lite and esd CAN-EtherCAT do the same)."""

    name: str
    is_ethercat: bool
    slave: Slave


def ethercat_devices(participants: Sequence[object]) -> list[EthercatDevice]:
    """The participants that join a segment (``is_ethercat`` and a ``slave``), in rig-file order."""
    found: list[EthercatDevice] = []
    for p in participants:
        if getattr(p, "is_ethercat", False) and isinstance(getattr(p, "slave", None), Slave):
            found.append(cast(EthercatDevice, p))
    return found
