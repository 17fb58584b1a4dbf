"""What every family of rig faults shares: :class:`FaultsCore` (lookups by name, the clock lock, timers)
and :class:`FaultBoard` (the EtherCAT faults active now, each with how it ends and how it is undone).

``rig.faults`` (:class:`gatewaylab.rig.faults.Faults`) is one class built from a mixin per family of faults,
each a subclass of :class:`FaultsCore` in its own module (``faults_ec_*.py``); every family adds its
methods, its rows of the request table (``REQUESTS``) and its verbs of ``gatewaylab fault``
(``gatewaylab/cli/fault_ec_*.py``). A family's fault that stays active for a while -- N frames, T seconds,
until healed -- is put on the board with :meth:`FaultsCore.activate`: ``ethercat-states`` and
``gatewaylab monitor`` list it, it ends by its count (:meth:`FaultsCore.finish`), its duration or
``ec-clear``, and its ``undo`` puts the segment back as a master's re-initialisation expects it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import Controller
from gatewaylab.common.clock import TimerHandle
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.ethercat.segment import Segment
from gatewaylab.plugin.capabilities import EthercatDevice, can_channels, ethercat_devices, segment_of

if TYPE_CHECKING:
    from gatewaylab.rig.runtime import Rig

__all__ = ["ActiveFault", "FaultBoard", "FaultRefused", "FaultsCore", "check_count", "check_seconds"]


class FaultRefused(GatewaylabError):
    """The rig cannot inject this fault (unknown bus or device, a device without that part)."""


def check_seconds(what: str, value: float, zero: bool = False) -> None:
    """A finite number of seconds > 0 (>= 0 with ``zero``), else :class:`FaultRefused`."""
    if not math.isfinite(value) or value < 0 or (value == 0 and not zero):
        raise FaultRefused(f"{what} must be a finite number of seconds {'>=' if zero else '>'} 0, got {value}")


def check_count(what: str, value: int) -> None:
    """A count >= 1, else :class:`FaultRefused`."""
    if value < 1:
        raise FaultRefused(f"{what} must be >= 1, got {value}")


@dataclass
class ActiveFault:
    """One EtherCAT fault in force: what ``ethercat-states`` lists, and how to end it."""

    ident: int
    #: the verb (``ec-lose``, ``ec-delay`` ...)
    fault: str
    #: a device name, or "segment" for what hits the whole line
    target: str
    #: JSON-ready arguments and progress (e.g. ``{"left": 3}``), shown as they are
    details: dict[str, Any]
    #: puts the segment back (called once, under ``clock.lock``)
    undo: Callable[[], None]
    #: the clock time it ends by itself (None: by count or on request)
    ends_at: float | None = None
    timer: TimerHandle | None = field(default=None, repr=False)

    def as_json(self) -> dict[str, Any]:
        """What ``ethercat-states`` and the monitor show of it."""
        out: dict[str, Any] = {"id": self.ident, "fault": self.fault, "target": self.target, **self.details}
        if self.ends_at is not None:
            out["ends_at"] = round(self.ends_at, 6)
        return out


class FaultBoard:
    """The EtherCAT faults active now, in the order they were injected."""

    def __init__(self) -> None:
        self._active: dict[int, ActiveFault] = {}
        self._ids = itertools.count(1)

    def add(self, fault: str, target: str, details: dict[str, Any], undo: Callable[[], None]) -> ActiveFault:
        """Put a fault on the board (its ``ident`` is new)."""
        entry = ActiveFault(next(self._ids), fault, target, details, undo)
        self._active[entry.ident] = entry
        return entry

    def end(self, ident: int) -> bool:
        """Undo and forget fault ``ident``; False when it had ended already."""
        entry = self._active.pop(ident, None)
        if entry is None:
            return False
        if entry.timer is not None:
            entry.timer.cancel()
        entry.undo()
        return True

    def end_all(self, target: str | None = None) -> list[ActiveFault]:
        """End every fault (of ``target`` only, when given); the ones ended."""
        ended = [e for e in self._active.values() if target is None or e.target == target]
        for e in ended:
            self.end(e.ident)
        return ended

    def entries(self) -> list[ActiveFault]:
        """The active faults, oldest first."""
        return list(self._active.values())

    def __len__(self) -> int:
        return len(self._active)


class FaultsCore:
    """The rig, its names and its clock, for every family of faults."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        #: pending power-ons and fault ends, cancelled when the rig closes
        self.timers: list[TimerHandle] = []
        #: the EtherCAT faults in force (``ethercat-states`` lists them)
        self.board = FaultBoard()
        #: (participants when found, the EtherCAT devices, the participants with a CAN side): the status
        #: requests (`gatewaylab monitor` asks twice a second, under ``clock.lock``) find them once, as a
        #: Protocol's ``isinstance`` costs ~20 us on Python 3.11 (a request for 18 slaves took 0.3 ms)
        self._found: tuple[int, list[EthercatDevice], list[Any]] | None = None

    # -- lookup -------------------------------------------------------------------------------------
    def bus(self, name: str) -> VirtualBus:
        """The rig's bus ``name`` (FaultRefused naming the buses there are)."""
        bus = self.rig.buses.get(name)
        if bus is None:
            raise FaultRefused(f"no bus {name!r} in this rig (buses: {', '.join(sorted(self.rig.buses))})")
        return bus

    def device(self, name: str) -> Any:
        """The rig's device (participant) ``name``."""
        for p in self.rig.participants:
            if p.name == name:
                return p
        names = ", ".join(p.name for p in self.rig.participants)
        raise FaultRefused(f"no device {name!r} in this rig (devices: {names})")

    def _participants_found(self) -> tuple[int, list[EthercatDevice], list[Any]]:
        participants = self.rig.participants
        found = self._found
        if found is None or found[0] != len(participants):   # the rig's build appends; nothing removes
            found = self._found = (len(participants), ethercat_devices(participants),
                                   [p for p in participants if can_channels(p)])
        return found

    def ethercat_devices(self) -> list[EthercatDevice]:
        """The rig's EtherCAT devices in rig-file order (plugin.capabilities.ethercat_devices, found once)."""
        return self._participants_found()[1]

    def can_sides(self) -> list[tuple[Any, dict[str, Controller]]]:
        """(participant, its CAN controllers by channel name) of those with a CAN side, in rig-file order."""
        return [(p, can_channels(p)) for p in self._participants_found()[2]]

    def segment(self) -> Segment:
        """The rig's ``[ethercat]`` segment."""
        segment = segment_of(self.rig.participants)
        if segment is None:
            raise FaultRefused("this rig has no [ethercat] segment")
        return segment

    def ethercat_position(self, device: str) -> tuple[Segment, int]:
        """The segment of EtherCAT device ``device`` and its position there (0: next to the master)."""
        p = self.device(device)
        if not ethercat_devices([p]):
            raise FaultRefused(f"{device} is not an EtherCAT device")
        slave = p.slave
        segment = segment_of(self.rig.participants)
        if segment is None or slave not in segment.slaves:
            raise FaultRefused(f"{device} is in no [ethercat] segment")
        return segment, segment.slaves.index(slave)

    # -- doing it -----------------------------------------------------------------------------------
    def locked(self, action: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        """Run ``action`` under ``clock.lock`` (the frame path and the loop hold it too)."""
        with self.rig.clock.lock:
            if self.rig.closed:
                raise FaultRefused("the rig is closed")
            return action()

    def run(self, action: Callable[[], None], result: dict[str, Any]) -> dict[str, Any]:
        """:meth:`locked` for an action that returns nothing: ``result`` is the answer."""
        def act() -> dict[str, Any]:
            action()
            return result
        return self.locked(act)

    def later(self, delay: float, callback: Callable[[], None]) -> TimerHandle:
        """Call ``callback`` after ``delay`` s of the rig's clock (cancelled when the rig closes)."""
        self.timers = [t for t in self.timers if not t.cancelled]
        handle = self.rig.clock.call_later(delay, callback)
        self.timers.append(handle)
        return handle

    def activate(self, fault: str, target: str, details: dict[str, Any], undo: Callable[[], None],
                 seconds: float | None = None) -> ActiveFault:
        """Put an active fault on the board (call under ``clock.lock``); with ``seconds`` it ends by itself
        then. The answer of the fault's method should include ``"id": entry.ident``."""
        entry = self.board.add(fault, target, details, undo)
        if seconds is not None:
            entry.ends_at = self.rig.clock.now() + seconds
            def end() -> None:
                self.board.end(entry.ident)
            entry.timer = self.later(seconds, end)
        return entry

    def finish(self, ident: int) -> None:
        """End an active fault from inside the rig (its count is used up); under ``clock.lock``."""
        self.board.end(ident)

    def cancel(self) -> None:
        """Forget pending fault steps (the rig closes)."""
        for t in self.timers:
            t.cancel()
        self.timers.clear()
