"""A rig's scenario in motion: each step's trigger armed on the rig's clock or on the segment's milestones
(:class:`~gatewaylab.ethercat.milestones.MilestoneWatch`), its fault fired through ``rig.faults.request``
(every family's verbs, as the control endpoint runs them), one log line per step, and what fired when for
``ethercat-states`` and ``gatewaylab monitor``.

A step fires once. Its time is the rig clock's time since the scenario was armed (``Rig.start``): on a
simulated clock, two runs of the same master give the same steps at the same times. A fault the rig refuses
when the step fires (a device already unplugged ...) is logged and listed with its error; the scenario goes
on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.milestones import MilestoneWatch
from gatewaylab.plugin import section_error
from gatewaylab.plugin.capabilities import ethercat_devices, segment_of
from gatewaylab.rig.scenario import END_VERBS, Step

if TYPE_CHECKING:
    from gatewaylab.ethercat.slave import Slave
    from gatewaylab.rig.runtime import Rig

__all__ = ["ScenarioRun"]

#: The scenario's log: one WARNING line per step fired or ended (an injected fault; shown by default).
log = logging.getLogger("gatewaylab.scenario")


class ScenarioRun:
    """The steps of one rig: checked against its devices when the rig is built, armed when it starts."""

    def __init__(self, rig: Rig, steps: tuple[Step, ...]) -> None:
        self.rig = rig
        self.steps = steps
        #: what fired, in order: step, at (s since armed), trigger, fault, answer or error (+ ended_at)
        self.fired: list[dict[str, Any]] = []
        self.started_at: float | None = None
        self.watch: MilestoneWatch | None = None
        names = {p.name for p in rig.participants}
        slaves = {p.name: p.slave for p in ethercat_devices(rig.participants)}
        self._slaves: dict[int, Slave] = {}
        for step in steps:
            if step.device is not None:
                if step.device not in slaves:
                    known = ", ".join(slaves) or "none"
                    raise section_error(step.where, f"{step.trigger}.device = {step.device!r} is not an EtherCAT "
                                                    f"device of this rig (EtherCAT devices: {known})")
                self._slaves[step.number] = slaves[step.device]
            device = step.request.get("device")
            if isinstance(device, str) and device not in names:
                raise section_error(step.where, f"device = {device!r} is no device of this rig "
                                                f"(devices: {', '.join(sorted(names))})")
        if any(s.trigger != "at" for s in steps):
            segment = segment_of(rig.participants)
            if segment is None:
                first = next(s for s in steps if s.trigger != "at")
                raise ConfigError(f"{first.where}: {first.trigger} needs an [ethercat] segment in the rig")
            self.watch = MilestoneWatch(segment)

    def arm(self) -> None:
        """Start the clock of the scenario and every trigger (call under ``clock.lock``, once)."""
        if self.started_at is not None:
            return
        self.started_at = self.rig.clock.now()
        for step in self.steps:
            if step.trigger == "at":
                self.rig.faults.later(float(step.value), self._firing(step))
                continue
            assert self.watch is not None
            met = self._met(step)
            if step.trigger == "after_cycles":
                self.watch.on_cycles(int(step.value), met)
            elif step.trigger == "after_state":
                self.watch.on_state(self._slaves[step.number], AlState[str(step.value)], met)
            else:
                self.watch.on_sdo(self._slaves[step.number], int(step.value), met)
        if self.watch is not None:
            self.watch.attach()

    def close(self) -> None:
        """Stop watching the segment (the rig closes; its timers are the faults' and go with them)."""
        if self.watch is not None:
            self.watch.detach()

    def _firing(self, step: Step) -> Callable[[], None]:
        def fire() -> None:
            self.fire(step)
        return fire

    def _met(self, step: Step) -> Callable[[], None]:
        def met() -> None:
            if step.delay:
                self.rig.faults.later(step.delay, self._firing(step))
            else:
                self.fire(step)
        return met

    def _now(self) -> float:
        return round(self.rig.clock.now() - (self.started_at or 0.0), 6)

    def fire(self, step: Step) -> None:
        """Run the step's fault now (on the rig's loop or in the frame path, under ``clock.lock``)."""
        record: dict[str, Any] = {"step": step.number, "at": self._now(), "trigger": step.describe(),
                                  "fault": step.request["fault"]}
        try:
            answer = self.rig.faults.request(step.request)
        except Exception as exc:   # isolation boundary: a refused step never stops the frame path or the loop
            record["error"] = str(exc)
            log.warning("scenario step %d (%s) at %.6f s: %s refused: %s", step.number, step.describe(),
                        record["at"], record["fault"], exc)
        else:
            record["answer"] = answer
            log.warning("scenario step %d (%s) at %.6f s: %s -> %s", step.number, step.describe(), record["at"],
                        record["fault"], _short(answer))
            if step.end_after is not None:
                self.rig.faults.later(step.end_after, lambda: self._end(step, record))
        self.fired.append(record)

    def _end(self, step: Step, record: dict[str, Any]) -> None:
        """``end_after`` has passed: end the step's fault (its board entry, or the verb that undoes it)."""
        answer = record.get("answer", {})
        try:
            if isinstance(answer.get("id"), int):
                ended = self.rig.faults.board.end(answer["id"])
                how = "ended" if ended else "had ended already"
            elif step.request["fault"] in END_VERBS:
                undo = {k: v for k, v in step.request.items() if k in ("device", "node", "bus", "channel")}
                self.rig.faults.request({**undo, "fault": END_VERBS[step.request["fault"]]})
                how = f"ended by {END_VERBS[step.request['fault']]}"
            else:
                how = "had nothing to end"
        except Exception as exc:   # isolation boundary, as for firing
            how = f"could not end: {exc}"
        record["ended_at"] = self._now()
        record["end"] = how
        log.warning("scenario step %d at %.6f s: %s %s", step.number, record["ended_at"], record["fault"], how)

    def as_json(self) -> dict[str, Any]:
        """What ``ethercat-states`` shows under "scenario": the number of steps and those fired so far."""
        return {"steps": len(self.steps), "fired": list(self.fired)}


def _short(answer: dict[str, Any]) -> str:
    """The answer for one log line (without the repeated verb)."""
    return ", ".join(f"{k}={v}" for k, v in answer.items() if k != "fault") or "done"
