"""EtherCAT faults of ports, cables and hot-connect groups: an open port, a break of a redundant ring, a hot-connect
group unplugged by its head (the mechanism: :mod:`gatewaylab.ethercat.ring` and ``Segment.cut`` / ``detach``).

Each stays on the fault board until it ends: ``ec-port-open`` after ``--seconds`` or on ``ec-clear``, ``ec-ring-break``
on ``ec-ring-heal`` or ``ec-clear``, ``ec-hot-unplug`` on ``ec-hot-plug`` or ``ec-clear``.
"""

from __future__ import annotations

from typing import Any

from gatewaylab.ethercat.ring import LOST, PORT_A, PORT_B
from gatewaylab.ethercat.segment import Segment
from gatewaylab.rig.faults_core import FaultRefused, FaultsCore, check_seconds
from gatewaylab.rig.segment import SegmentParticipant

__all__ = ["EC_RING_REQUESTS", "EcRingFaults"]

_EXITS = {PORT_A: "primary", PORT_B: "secondary", LOST: None}


def _line(segment: Segment) -> dict[str, Any]:
    """Who answers through which interface now (what the answers show)."""
    exit_a = _EXITS[segment.exit_a]
    return {"primary": [s.name for s in segment.reached], "secondary": [s.name for s in segment.reached_secondary],
            "primary_returns_on": exit_a}


class EcRingFaults(FaultsCore):
    """``ec-port-open``, ``ec-ring-break`` / ``ec-ring-heal``, ``ec-hot-unplug`` / ``ec-hot-plug``."""

    def ec_port_open(self, device: str, port: int, seconds: float | None = None) -> dict[str, Any]:
        """Open port ``port`` (0: towards the master, 1: away from it) of ``device``: the cable there loses its
        link, both ports close, the slaves behind it vanish from a line (a redundant master still reaches them
        through its secondary interface)."""
        if seconds is not None:
            check_seconds("seconds", seconds)
        if port not in (0, 1, 2, 3):
            raise FaultRefused(f"an ESC has ports 0 to 3, not {port}")
        if port > 1:
            raise FaultRefused(f"port {port} of {device} has no cable (the line uses ports 0 and 1): nothing to open")
        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(device)
            gap = position + port
            segment.cut(gap)
            def undo() -> None:
                segment.join(gap)
            entry = self.activate("ec-port-open", device, {"port": port}, undo, seconds)
            return {"fault": "ec-port-open", "id": entry.ident, "device": device, "port": port, "position": position,
                    **_line(segment)}
        return self.locked(act)

    def ec_ring_break(self, after_device: str) -> dict[str, Any]:
        """Break the cable after ``after_device`` (to the next slave, or to the secondary interface after the last):
        a redundant master reaches the slaves before the break through the primary interface, those after it
        through the secondary one."""
        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(after_device)
            if not segment.redundant:
                raise FaultRefused("the [ethercat] segment is a line, not a ring (set [ethercat] redundant): "
                                   "use ec-port-open DEVICE 1 to cut a line")
            gap = position + 1
            if any(e.fault == "ec-ring-break" and e.details.get("gap") == gap for e in self.board.entries()):
                raise FaultRefused(f"the ring is broken after {after_device} already")
            segment.cut(gap)
            def undo() -> None:
                segment.join(gap)
            entry = self.activate("ec-ring-break", after_device, {"gap": gap}, undo)
            return {"fault": "ec-ring-break", "id": entry.ident, "after_device": after_device, **_line(segment)}
        return self.locked(act)

    def ec_ring_heal(self) -> dict[str, Any]:
        """Mend every ring break: frames from the primary interface pass every slave again."""
        def act() -> dict[str, Any]:
            healed = [e for e in self.board.entries() if e.fault == "ec-ring-break"]
            for e in healed:
                self.board.end(e.ident)
            return {"fault": "ec-ring-heal", "healed": [e.target for e in healed], **_line(self.segment())}
        return self.locked(act)

    def _group(self, head: str) -> list[int]:
        for p in self.rig.participants:
            if isinstance(p, SegmentParticipant):
                if head not in p.hot_groups:
                    heads = ", ".join(p.hot_groups) or "none: set [ethercat] hot_connect"
                    raise FaultRefused(f"{head} heads no hot-connect group (heads: {heads})")
                return p.hot_groups[head]
        raise FaultRefused("this rig has no [ethercat] segment")

    def ec_hot_unplug(self, head: str) -> dict[str, Any]:
        """Unplug the hot-connect group ``head`` heads: its devices leave the line, the devices after it stay (at
        positions one group shorter), as a group hanging off a junction port."""
        def act() -> dict[str, Any]:
            segment = self.segment()
            group = self._group(head)
            if any(e.fault == "ec-hot-unplug" and e.target == head for e in self.board.entries()):
                raise FaultRefused(f"the hot-connect group of {head} is unplugged already")
            segment.detach(group)
            def undo() -> None:
                segment.attach(group)
            names = [segment.slaves[p].name for p in group]
            entry = self.activate("ec-hot-unplug", head, {"group": names}, undo)
            return {"fault": "ec-hot-unplug", "id": entry.ident, "head": head, "group": names, **_line(segment)}
        return self.locked(act)

    def ec_hot_plug(self, head: str) -> dict[str, Any]:
        """Plug the hot-connect group of ``head`` back in: its devices power on in INIT at their places."""
        def act() -> dict[str, Any]:
            self._group(head)
            ended = [e for e in self.board.entries() if e.fault == "ec-hot-unplug" and e.target == head]
            if not ended:
                raise FaultRefused(f"the hot-connect group of {head} is not unplugged")
            for e in ended:
                self.board.end(e.ident)
            return {"fault": "ec-hot-plug", "head": head, **_line(self.segment())}
        return self.locked(act)


_R, _O = True, False

#: fault name -> (method, {argument: (JSON type, required)}), as ``REQUESTS`` in rig/faults.py
EC_RING_REQUESTS: dict[str, tuple[str, dict[str, tuple[str, bool]]]] = {
    "ec-port-open": ("ec_port_open", {"device": ("string", _R), "port": ("int", _R), "seconds": ("number", _O)}),
    "ec-ring-break": ("ec_ring_break", {"after_device": ("string", _R)}),
    "ec-ring-heal": ("ec_ring_heal", {}),
    "ec-hot-unplug": ("ec_hot_unplug", {"head": ("string", _R)}),
    "ec-hot-plug": ("ec_hot_plug", {"head": ("string", _R)}),
}
