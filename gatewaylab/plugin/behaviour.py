"""Process values without code: the ``[device.behaviour]`` table of a device built from a description file.

A device built from an EDS (``canopen_node``) keeps its dictionary's defaults and stores what it is
written; these rules make entries move by themselves, evaluated on the rig's clock each behaviour
tick (docs/bring-your-own-network.md)::

    [device.behaviour]
    "0x6000:01" = { echo = "0x6200:01" }                  # a copy of another entry (an output looped back)
    "0x2001" = "counter"                                  # +1 per tick, wraps within the entry's type
    "0x2002" = { counter = 5 }                            # +5 per tick
    "0x6401:01" = { sine = { amplitude = 1000, period = 2.0, offset = 0 } }
    "0x2003" = { ramp = { from = 0, to = 100, period = 1.0 } }   # sawtooth from..to every period
    "0x2004" = { value = 42 }
    "0x2005" = { random = { min = 0, max = 100 } }        # reproducible: seeded by the address

Keys are ``"INDEX"`` (sub-index 0) or ``"INDEX:SUB"`` in hex. A rule is checked against the dictionary
when the device is built (the entry exists, the rule fits its type); each failure is one ConfigError
line. ``hook = "package.module:function"`` on the device adds Python: ``function(values, t)`` once per
tick after the rules, with ``values`` a :class:`BehaviourValues` (get/set by address).
"""

from __future__ import annotations

import importlib
import math
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.od import DataType, Entry, ObjectDictionary, coerce
from gatewaylab.od.types import FLOAT_TYPES, type_range

__all__ = ["Behaviour", "BehaviourValues", "Rule", "load_hook", "parse_address", "parse_behaviour"]

Address = tuple[int, int]
RULES = ("echo", "counter", "sine", "ramp", "value", "random")


@dataclass(frozen=True, slots=True)
class Rule:
    """One entry's rule: its kind and parameters (checked against the entry)."""

    address: Address
    kind: str
    #: echo: the source address; counter: step; sine: amplitude, period, offset; ramp: from, to, period;
    #: value: the value; random: min, max
    params: tuple[Any, ...]


def parse_address(text: str) -> Address:
    """``"0x6000:01"`` / ``"6000:1"`` / ``"0x2001"`` -> (index, subindex); ConfigError (or ValueError from
    ``int``) otherwise."""
    index_text, _, sub_text = text.strip().partition(":")
    index = int(index_text, 16)
    sub = int(sub_text, 16) if sub_text else 0
    if not (0 <= index <= 0xFFFF and 0 <= sub <= 0xFF):
        raise ConfigError(f"{text!r} is outside 0x0000..0xFFFF:00..FF")
    return index, sub


def _number(table: Mapping[str, Any], key: str, default: float | None = None) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key} must be a number" + ("" if key in table else " (missing)"))
    return float(value)


def _rule(address: Address, raw: Any, od: ObjectDictionary) -> Rule:
    params: Any
    if isinstance(raw, str):
        kind, params = raw, {}
    elif isinstance(raw, dict) and len(raw) == 1:
        kind, params = next(iter(raw.items()))
    else:
        raise ConfigError(f"wants one rule ({', '.join(RULES)}): a name or a table with one key")
    if kind not in RULES:
        raise ConfigError(f"unknown rule {kind!r} (known: {', '.join(RULES)})")
    entry = od.entries.get(address)
    if entry is None:
        raise ConfigError("no such entry in the dictionary")
    numeric = type_range(entry.data_type) is not None or entry.data_type in FLOAT_TYPES
    if kind != "echo" and kind != "value" and not numeric:
        raise ConfigError(f"{kind} needs a numeric entry ({entry.data_type.name} is not)")
    if kind == "echo":
        if not isinstance(params, str):
            raise ConfigError('echo wants the source address, e.g. { echo = "0x6200:01" }')
        source = parse_address(params)
        if source not in od.entries:
            raise ConfigError(f"echo source {params!r} is not in the dictionary")
        return Rule(address, kind, (source,))
    if kind == "counter":
        step = 1.0 if params == {} else params
        if isinstance(step, bool) or not isinstance(step, (int, float)):
            raise ConfigError("counter wants a step number, e.g. { counter = 5 }")
        return Rule(address, kind, (step,))
    if kind == "value":
        try:
            return Rule(address, kind, (coerce(entry, params),))
        except (ConfigError, ValueError, TypeError) as exc:
            raise ConfigError(f"value {params!r} does not fit {entry.data_type.name}: {exc}") from None
    if not isinstance(params, dict):
        raise ConfigError(f"{kind} wants a table of parameters")
    if kind == "sine":
        period = _number(params, "period")
        if period <= 0:
            raise ConfigError("sine period must be > 0 s")
        return Rule(address, kind, (_number(params, "amplitude"), period, _number(params, "offset", 0.0)))
    if kind == "ramp":
        period = _number(params, "period")
        if period <= 0:
            raise ConfigError("ramp period must be > 0 s")
        return Rule(address, kind, (_number(params, "from", 0.0), _number(params, "to"), period))
    low, high = _number(params, "min"), _number(params, "max")
    if low > high:
        raise ConfigError("random min > max")
    return Rule(address, kind, (low, high))


def parse_behaviour(table: Mapping[str, Any], od: ObjectDictionary) -> tuple[Rule, ...]:
    """The rules of a ``[device.behaviour]`` table, each checked against ``od``; a one-line ConfigError
    ``behaviour KEY: problem`` for the first rule that does not fit (the rig prefixes the section)."""
    rules: list[Rule] = []
    for key, raw in table.items():
        try:
            rules.append(_rule(parse_address(key), raw, od))
        except (ConfigError, ValueError) as exc:
            raise ConfigError(f"behaviour {key!r}: {exc}") from None
    return tuple(rules)


def load_hook(spec: str) -> Callable[[BehaviourValues, float], None]:
    """The callable named ``package.module:function`` (a one-line ConfigError ``hook ...`` otherwise)."""
    module_name, _, attr = spec.partition(":")
    try:
        function = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ConfigError(f"hook {spec!r} cannot be loaded ({exc})") from None
    if not callable(function):
        raise ConfigError(f"hook {spec!r} is not callable")
    return function  # type: ignore[no-any-return]


class BehaviourValues:
    """What a hook sees: the dictionary's typed values by address (no access checks, as device code)."""

    __slots__ = ("_od",)

    def __init__(self, od: ObjectDictionary) -> None:
        self._od = od

    def get(self, index: int, subindex: int = 0) -> Any:
        """The typed value of an entry."""
        return self._od.get(index, subindex)

    def set(self, index: int, subindex: int, value: Any) -> None:
        """Set an entry (event-driven PDOs see the change)."""
        self._od.put(index, subindex, value)


def _fitter(entry: Entry) -> Callable[[float], Any]:
    """How a computed number is stored in ``entry``'s type: rounded and wrapped into an integer range."""
    if entry.data_type in FLOAT_TYPES:
        return float
    if entry.data_type is DataType.BOOLEAN:
        return lambda value: bool(round(value) & 1)
    rng = type_range(entry.data_type)
    if rng is None:
        return round
    low, span = rng[0], rng[1] - rng[0] + 1
    return lambda value: (round(value) - low) % span + low


class Behaviour:
    """The rules (and hook) of one device, applied to its dictionary by :meth:`apply` each tick."""

    def __init__(self, rules: tuple[Rule, ...], od: ObjectDictionary,
                 hook: Callable[[BehaviourValues, float], None] | None = None) -> None:
        self.rules = rules
        self.od = od
        self.hook = hook
        self.values = BehaviourValues(od)
        self._random = {rule.address: random.Random(rule.address[0] << 8 | rule.address[1]) for rule in rules}
        #: each rule with what it needs per tick worked out once: (index, subindex, kind, params, how a number
        #: is stored in the entry's type, whether an echo wraps its value into an integer range)
        self._plan: list[tuple[int, int, str, tuple[Any, ...], Callable[[float], Any], bool]] = []
        for rule in rules:
            entry = od.entries[rule.address]
            wrap = type_range(entry.data_type) is not None
            self._plan.append((*rule.address, rule.kind, rule.params, _fitter(entry), wrap))
        #: hook calls that raised (the device carries on and logs the first) and the last exception
        self.hook_errors = 0
        self.last_hook_error: Exception | None = None

    def apply(self, t: float) -> None:
        """Evaluate every rule at time ``t`` (seconds on the rig's clock) and store the results."""
        od = self.od
        get, put = od.get, od.put
        for index, sub, kind, p, fit, wrap in self._plan:
            if kind == "echo":
                value: Any = get(*p[0])
                if wrap and isinstance(value, (int, float)):
                    value = fit(value)
            elif kind == "counter":
                value = fit(float(get(index, sub)) + p[0])
            elif kind == "sine":
                value = fit(p[2] + p[0] * math.sin(2 * math.pi * t / p[1]))
            elif kind == "ramp":
                value = fit(p[0] + (p[1] - p[0]) * ((t % p[2]) / p[2]))
            elif kind == "random":
                value = fit(self._random[(index, sub)].uniform(p[0], p[1]))
            else:
                value = p[0]
            if get(index, sub) != value:
                put(index, sub, value)
        if self.hook is not None:
            try:
                self.hook(self.values, t)
            except Exception as exc:   # a user's hook must not stop the rig: counted, the device carries on
                self.hook_errors += 1
                self.last_hook_error = exc
