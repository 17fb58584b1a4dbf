"""Scenarios: faults fired in a fixed order at fixed milestones, so a CI job meets the same sequence every run.

A scenario is a list of steps, ``[[scenario]]`` tables in the rig file or in a file of their own
(``gatewaylab run --scenario FILE``, which holds nothing else and replaces the rig file's list)::

    [[scenario]]
    after_state = {device = "io1", state = "OP"}   # the trigger: exactly one of at, after_state,
    delay = 0.5                                      #   after_cycles, after_sdo; delay: seconds after it
    fault = "ethercat-unplug"                        # any `gatewaylab fault` verb ...
    device = "io1"                                   # ... with its control-request arguments
    end_after = 2.0                                  # optional: ends the fault (replug, ec-clear) 2 s later

Every other key of a step is an argument of its fault, checked when the scenario loads against the request
table the control endpoint uses (:func:`gatewaylab.rig.faults.check_request`): an unknown verb, argument or
type, an unknown trigger or a bad value is one :class:`ConfigError` line naming the file, the step and the
key (``gatewaylab run`` exits 2). The steps run in :mod:`gatewaylab.rig.scenario_run`; docs/faults.md
"Scenarios" says what each trigger means exactly.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.plugin import section_error
from gatewaylab.rig.faults import REQUESTS, check_request
from gatewaylab.rig.faults_core import FaultRefused

__all__ = ["END_VERBS", "STEP_KEYS", "TRIGGERS", "Step", "load_scenario", "parse_scenario"]

#: The keys that pick when a step fires; a step has exactly one.
TRIGGERS = ("at", "after_state", "after_cycles", "after_sdo")
#: The keys of a step that are not its fault's arguments.
STEP_KEYS = (*TRIGGERS, "delay", "end_after", "fault")
#: Faults ``end_after`` ends with another verb (the ``ec-*`` faults end through the active-fault board).
END_VERBS = {"ethercat-unplug": "ethercat-replug", "can-unplug": "can-replug", "usb-unplug": "usb-replug"}
#: Requests that only report: no step fires them.
_STATUS = ("ethercat-states", "can-states")
#: ``ec-*`` verbs that put nothing on the board for ``end_after`` to end.
_NOT_ENDABLE = ("ec-clear", "ec-ring-heal")


@dataclass(frozen=True, slots=True)
class Step:
    """One validated step: its trigger, its fault request and how long that lasts."""

    #: 1 for the first ``[[scenario]]`` table
    number: int
    #: one of :data:`TRIGGERS`
    trigger: str
    #: ``at``: seconds; ``after_cycles``: a count; ``after_state``: an AL state name; ``after_sdo``: an index
    value: float | int | str
    #: the device of ``after_state`` / ``after_sdo``
    device: str | None
    #: the control request it fires: ``{"fault": VERB, ...arguments}``
    request: dict[str, Any] = field(default_factory=dict)
    delay: float = 0.0
    end_after: float | None = None
    #: how errors name it: ``FILE [[scenario]] #N``
    where: str = ""

    def describe(self) -> str:
        """The trigger in words, as the log and the monitor show it."""
        if self.trigger == "at":
            text = f"at {self.value} s"
        elif self.trigger == "after_cycles":
            text = f"after cycle {self.value}"
        elif self.trigger == "after_state":
            text = f"after {self.device} reached {self.value}"
        else:
            text = f"after SDO to {self.device} 0x{int(self.value):04X}"
        return text + (f" + {self.delay} s" if self.delay else "")

    def as_json(self) -> dict[str, Any]:
        """The step as a TOML/JSON table again (what ``--scenario`` reads)."""
        out: dict[str, Any] = {}
        if self.trigger == "after_state":
            out["after_state"] = {"device": self.device, "state": self.value}
        elif self.trigger == "after_sdo":
            out["after_sdo"] = {"device": self.device, "index": self.value}
        else:
            out[self.trigger] = self.value
        if self.delay:
            out["delay"] = self.delay
        if self.end_after is not None:
            out["end_after"] = self.end_after
        return {**out, **self.request}


def _seconds(where: str, key: str, value: Any, zero: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value < 0 or (value == 0 and not zero):
        raise section_error(where, f"{key} must be a number of seconds {'>=' if zero else '>'} 0, got {value!r}")
    return float(value)


def _trigger_table(where: str, key: str, raw: Any, second: str) -> tuple[str, Any]:
    if not isinstance(raw, Mapping):
        raise section_error(where, f"{key} must be a table {{device = \"NAME\", {second} = ...}}, got {raw!r}")
    unknown = sorted(set(raw) - {"device", second})
    if unknown:
        raise section_error(where, f"unknown {key} keys {unknown} (allowed: device, {second})")
    device = raw.get("device")
    if not isinstance(device, str) or not device:
        raise section_error(where, f"{key}.device must be a device name (a string), got {device!r}")
    if second not in raw:
        raise section_error(where, f"{key} needs {second}")
    return device, raw[second]


def _step(raw: Any, number: int, where: str) -> Step:
    if not isinstance(raw, Mapping):
        raise section_error(where, "must be a table")
    triggers = [k for k in TRIGGERS if k in raw]
    if not triggers:
        raise section_error(where, f"needs a trigger: one of {', '.join(TRIGGERS)}")
    if len(triggers) > 1:
        raise section_error(where, f"has {len(triggers)} triggers ({', '.join(triggers)}): one per step")
    trigger = triggers[0]
    device: str | None = None
    value: float | int | str
    if trigger == "at":
        value = _seconds(where, "at", raw["at"], zero=True)
    elif trigger == "after_cycles":
        n = raw["after_cycles"]
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise section_error(where, f"after_cycles must be a whole number >= 1, got {n!r}")
        value = n
    elif trigger == "after_state":
        device, state = _trigger_table(where, trigger, raw[trigger], "state")
        if not isinstance(state, str) or state.upper() not in AlState.__members__:
            raise section_error(where, f"after_state.state must be one of {', '.join(AlState.__members__)}, "
                                       f"got {state!r}")
        value = state.upper()
    else:
        device, index = _trigger_table(where, trigger, raw[trigger], "index")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index <= 0xFFFF:
            raise section_error(where, f"after_sdo.index must be an object index 0x0000..0xFFFF, got {index!r}")
        value = index
    delay = _seconds(where, "delay", raw["delay"], zero=True) if "delay" in raw else 0.0
    if "delay" in raw and trigger == "at":
        raise section_error(where, "delay goes with a milestone trigger; with at, add it to at")
    verb = raw.get("fault")
    if not isinstance(verb, str):
        raise section_error(where, f"needs fault = \"VERB\" (a `gatewaylab fault` verb), got {verb!r}")
    if verb in _STATUS:
        raise section_error(where, f"fault = {verb!r} is a status request, not a fault")
    request = {"fault": verb, **{k: v for k, v in raw.items() if k not in STEP_KEYS}}
    if verb in REQUESTS and (clash := [k for k in REQUESTS[verb][1] if k in STEP_KEYS]):
        raise section_error(where, f"fault {verb!r} has arguments named like step keys ({', '.join(clash)})")
    try:
        check_request(request)
    except FaultRefused as exc:
        key = "fault" if verb not in REQUESTS else "arguments"
        raise section_error(where, f"{key}: {exc}") from None
    end_after: float | None = None
    if "end_after" in raw:
        end_after = _seconds(where, "end_after", raw["end_after"], zero=False)
        if verb not in END_VERBS and (not verb.startswith("ec-") or verb in _NOT_ENDABLE):
            raise section_error(where, f"end_after: {verb} is not a fault end_after can end (it ends the ec-* "
                                       f"faults and {', '.join(END_VERBS)}; {verb} ends by its own arguments)")
    return Step(number, trigger, value, device, request, delay, end_after, where)


def parse_scenario(raw: Any, source: str) -> tuple[Step, ...]:
    """Validate the ``scenario`` array of a decoded rig or scenario file; one ConfigError line on a problem."""
    if not isinstance(raw, list):
        raise ConfigError(f"{source}: [[scenario]] must be an array of tables ([[scenario]], not [scenario])")
    return tuple(_step(entry, i + 1, f"{source} [[scenario]] #{i + 1}") for i, entry in enumerate(raw))


def load_scenario(path: str | Path) -> tuple[Step, ...]:
    """Read a scenario file (``[[scenario]]`` tables and nothing else)."""
    source = str(path)
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read scenario file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"scenario file {path} is not UTF-8 text (TOML)") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    unknown = sorted(set(data) - {"scenario"})
    if unknown:
        raise ConfigError(f"{source}: unknown top-level keys {unknown} (a scenario file holds [[scenario]] "
                          "tables only)")
    if "scenario" not in data:
        raise ConfigError(f"{source}: no [[scenario]] step")
    return parse_scenario(data["scenario"], source)
