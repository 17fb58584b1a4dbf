"""What ``gatewaylab monitor`` shows of a rig's scenario: one ``ethercat`` event per step as it fires or ends,
read from the "scenario" part of the control request ``ethercat-states`` (docs/faults.md "Scenarios")."""

from __future__ import annotations

from typing import Any

from gatewaylab.canopen.monitor import MonitorEvent

__all__ = ["ScenarioSeen"]


class ScenarioSeen:
    """The scenario steps already shown; :meth:`changes` gives the events of those new since."""

    def __init__(self) -> None:
        self._shown: set[tuple[int, str]] = set()

    def changes(self, answer: dict[str, Any], now: float) -> list[MonitorEvent]:
        """An event for each step fired (and each ended) since the last answer, in the order it happened."""
        scenario = answer.get("scenario")
        if not isinstance(scenario, dict):
            return []
        events = []
        total = scenario.get("steps", "?")
        for rec in scenario.get("fired") or []:
            step = rec.get("step")
            if (step, "fired") not in self._shown:
                self._shown.add((step, "fired"))
                outcome = f"refused: {rec['error']}" if "error" in rec else "fired"
                text = (f"EtherCAT scenario step {step}/{total} ({rec.get('trigger')}) at {rec.get('at')} s: "
                        f"{rec.get('fault')} {outcome}")
                events.append(MonitorEvent(now, "ethercat", text, None, {"scenario": rec}))
            if "ended_at" in rec and (step, "ended") not in self._shown:
                self._shown.add((step, "ended"))
                text = (f"EtherCAT scenario step {step}/{total} at {rec['ended_at']} s: "
                        f"{rec.get('fault')} {rec.get('end')}")
                events.append(MonitorEvent(now, "ethercat", text, None, {"scenario": rec}))
        return events
