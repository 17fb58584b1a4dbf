"""The active EtherCAT faults in ``gatewaylab monitor``: the "faults" of the rig's ``ethercat-states`` answer
(rig/faults_core.py's board), one log event when a fault starts and one when it ends (its count used up,
its time over, ``ec-clear``), so the log says which fault was in force while the master saw its symptoms."""

from __future__ import annotations

from typing import Any

from gatewaylab.canopen.monitor import MonitorEvent

__all__ = ["FaultWatch", "describe_fault"]

#: board fields that are not the fault's arguments
_FIXED = ("id", "fault", "target", "hits", "left", "ends_at")


def describe_fault(entry: dict[str, Any]) -> str:
    """One line of an active fault: verb, target, arguments, what is left (e.g. ``ec-lose on segment
    (replies=False, cmd=LRW), 2 left``)."""
    args = ", ".join(f"{k}={','.join(map(str, v)) if isinstance(v, list) else v}" for k, v in entry.items()
                     if k not in _FIXED)
    text = f"{entry.get('fault', '?')} on {entry.get('target', '?')}" + (f" ({args})" if args else "")
    if entry.get("left") is not None:
        text += f", {entry['left']} left"
    if entry.get("ends_at") is not None:
        text += f", until t={entry['ends_at']:.3f} s"
    return text


class FaultWatch:
    """The faults seen in the last answer, by id: what started and what ended since."""

    def __init__(self) -> None:
        self.active: dict[int, dict[str, Any]] = {}

    def changes(self, faults: list[dict[str, Any]] | None, now: float) -> list[MonitorEvent]:
        """Events for the faults that appeared and the ones that are gone since the last answer."""
        current = {int(e["id"]): e for e in faults or () if isinstance(e, dict) and "id" in e}
        events = [MonitorEvent(now, "ethercat", f"EtherCAT fault #{i} active: {describe_fault(e)}", None,
                               {"fault_state": "active", **e})
                  for i, e in current.items() if i not in self.active]
        events += [MonitorEvent(now, "ethercat", f"EtherCAT fault #{i} ended: {e.get('fault', '?')} on "
                                f"{e.get('target', '?')}", None, {"fault_state": "ended", **e})
                   for i, e in self.active.items() if i not in current]
        self.active = current
        return events
