"""What a device plugin implements and what it may use of the rig (docs/devices/writing-a-device.md).

A device package (inside gatewaylab or outside it) adds a rig-file ``kind`` by exposing a
:class:`DeviceKind` through the ``gatewaylab.devices`` entry-point group::

    [project.entry-points."gatewaylab.devices"]
    echo = "gatewaylab_example_device:KIND"

The rig validates every section against the kind's :class:`Key` table (one shared validator:
unknown keys, types, ranges, bus names; each failure a one-line :class:`ConfigError` naming the
file, the section and the key), then calls ``kind.create(rig, cfg)`` with a :class:`RigContext`
and the validated section (every key present, defaults filled in).

It lives in ``plugin/``, above the protocol packages (it names their types) and below ``devices/``,
and ``devices/`` import it without an upward dependency; ``gatewaylab.plugin`` re-exports it as
the public name for device packages outside gatewaylab.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import Controller
from gatewaylab.common.build_cache import BuildCache
from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError

__all__ = [
    "CheckedSection", "DeviceKind", "Factory", "Key", "Participant", "ParticipantBase", "RigContext", "section_error",
    "validate_table",
]


class Participant(Protocol):
    """Anything a rig-file section creates: drives, gateways, EtherCAT segments, plugin devices."""

    name: str

    def start(self) -> None:
        """Called once every participant exists: open endpoints, attach, start timers."""

    def stop(self) -> None:
        """Release what start() took (endpoints, files, threads); returns within milliseconds."""

    def ready_info(self) -> dict[str, Any]:
        """What the participant adds to the --ready-file JSON (deep-merged with the others)."""


class ParticipantBase:
    """A base a participant may derive from (it is a :class:`Participant`): the controllers it attaches
    through :meth:`attach` are detached by :meth:`detach_all`, which :meth:`stop` calls, so attach and
    detach are symmetric: a stopped participant (the rig closing, a power cycle) leaves nothing on a bus,
    and one that attaches in :meth:`start` can start again. Its section is checked once by the rig
    (:class:`CheckedSection`); a subclass that checks what it is given pays nothing for it."""

    def __init__(self, rig: RigContext, name: str) -> None:
        self.rig = rig
        self.name = name
        #: what :meth:`attach` attached and :meth:`detach_all` has not detached yet, in attachment order
        self.controllers: list[Controller] = []

    def attach(self, bus: str | VirtualBus, label: str, **options: Any) -> Controller:
        """A controller on ``bus`` (a rig bus name, or the bus) named ``label``, detached again by
        :meth:`detach_all`; ``options`` are :meth:`VirtualBus.attach`'s."""
        vbus = self.rig.bus(bus) if isinstance(bus, str) else bus
        ctrl = vbus.attach(label, **options)
        self.controllers.append(ctrl)
        return ctrl

    def detach_all(self) -> None:
        """Detach every controller :meth:`attach` attached, the last one first (idempotent)."""
        controllers = self.controllers
        while controllers:
            ctrl = controllers.pop()
            ctrl.bus.detach(ctrl)

    def start(self) -> None:
        """Nothing to open by default."""

    def stop(self) -> None:
        """Detach what :meth:`attach` attached; a subclass releases its own resources, then calls this."""
        self.detach_all()

    def ready_info(self) -> dict[str, Any]:
        """Nothing for the --ready-file by default."""
        return {}


class RigContext(Protocol):
    """What a factory and its participant may use of the rig they are built into."""

    @property
    def clock(self) -> Clock:
        """The one clock: schedule with call_later/call_every, never sleep."""

    @property
    def buses(self) -> Mapping[str, VirtualBus]:
        """The rig's buses by name."""

    @property
    def realtime(self) -> bool:
        """False: a simulated clock, nothing runs by itself (open no servers that wait on it)."""

    @property
    def state_dir(self) -> Path:
        """The run's own folder: sockets, stored parameters."""

    @property
    def base_dir(self) -> Path:
        """Where relative paths of the rig file start: its folder (the working folder for a rig from a dict)."""

    @property
    def participants(self) -> Sequence[Participant]:
        """The participants built so far, in rig-file order."""

    @property
    def build_cache(self) -> BuildCache:
        """What the sections of this build share: files read and parsed once (``build_cache.part(cls)``)."""

    def bus(self, name: str) -> VirtualBus:
        """The bus of that name (a ConfigError naming the declared ones otherwise)."""

    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` on the rig's loop, holding clock.lock, when ``fd`` is readable."""

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` for readability."""

    def add_writer(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` on the rig's loop, holding clock.lock, when ``fd`` is writable."""

    def remove_writer(self, fd: int) -> None:
        """Stop watching ``fd`` for writability."""

    def wake(self) -> None:
        """Interrupt the loop's wait (safe from any thread), e.g. after changing what it waits for."""


Factory = Callable[[RigContext, dict[str, Any]], Participant]


@dataclass(frozen=True, slots=True)
class Key:
    """One key of a rig-file section: its type, whether it is required, its default and range.

    ``type`` is ``int`` (not bool), ``float`` (an int is accepted), ``str`` (non-empty), ``bool``
    or ``dict`` (an inline table checked against ``keys``). ``bus=True``: the value names a
    declared ``[[bus]]``. ``false_is_none=True``: ``false`` switches the option off (None).
    """

    type: type
    default: Any = None
    required: bool = False
    min: float | None = None
    max: float | None = None
    choices: tuple[Any, ...] | None = None
    bus: bool = False
    hex: bool = False
    false_is_none: bool = False
    keys: Mapping[str, Key] | None = None
    #: Appended to a range or type error in parentheses: what the value means.
    help: str = ""
    #: The value names something of the rig and may become a file name in its folder (a socket, stored
    #: parameters): it must follow the name rule (:func:`name_problem`). Every kind's ``name`` key is
    #: checked so whether or not it says so.
    name: bool = False


@dataclass(frozen=True, slots=True)
class DeviceKind:
    """A rig-file ``kind``: its factory and its keys (besides ``kind``)."""

    kind: str
    create: Factory
    keys: Mapping[str, Key]
    #: One line for listings and errors ("kind 'x' is not installed (known: ...)").
    summary: str = ""
    #: The kind also has a top-level section of its own: "drive" -> ``[[drive]]``, "ethercat" ->
    #: ``[ethercat]`` (a single table when ``single``; built after every other section).
    table: str | None = None
    single: bool = False
    #: Its ``node_id`` and ``serial`` on ``bus`` are a CANopen node-ID and an LSS serial number,
    #: which must be unique on that bus.
    canopen: bool = False
    #: The participant's name when the section gives none (default: the ``name`` key's default).
    default_name: Callable[[Mapping[str, Any]], str] | None = None

    def name_of(self, cfg: Mapping[str, Any]) -> str | None:
        """The participant's name: the section's ``name``, or the kind's default for it."""
        name = cfg.get("name")
        if isinstance(name, str):
            return name
        return self.default_name(cfg) if self.default_name is not None else None

    def validate(self, cfg: Mapping[str, Any], where: str, buses: Sequence[str] | None = None) -> dict[str, Any]:
        """The section checked against :attr:`keys` (``kind`` itself is allowed and dropped), as a
        :class:`CheckedSection`; a section this kind checked already is returned as it is (validate once:
        the rig checks every section before it builds anything, and a participant that checks what it is
        given, to be usable without a rig, does not check it again)."""
        if isinstance(cfg, CheckedSection) and cfg.kind == self.kind:
            return cfg
        keys = self.keys
        own = keys.get("name")
        if own is not None and own.type is str and not own.name:   # names become file names: checked for every kind
            keys = {**keys, "name": replace(own, name=True)}
        return CheckedSection(self.kind, validate_table({k: v for k, v in cfg.items() if k != "kind"},
                                                        keys, where, buses))


class CheckedSection(dict[str, Any]):
    """A rig-file section checked against the keys of the kind named :attr:`kind` (every key present,
    defaults filled in): :meth:`DeviceKind.validate` of that kind passes it through unchecked."""

    __slots__ = ("kind",)

    def __init__(self, kind: str, items: Mapping[str, Any]) -> None:
        super().__init__(items)
        self.kind = kind


#: The longest name (docs/rig.md "Names"): a bus's socket ``TMPDIR/gatewaylab-XXXXXXXX/NAME.sock`` must fit
#: AF_UNIX's 107-byte path, which leaves 49 characters for TMPDIR (macOS's per-user TMPDIR is 49 long).
NAME_MAX = 32
NAME_RULE = (f"1..{NAME_MAX} characters of A-Z a-z 0-9 _ . @ -, not starting with . @ or - "
             f"(a name becomes a file name in the rig's folder)")
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.@-]*")


def name_problem(name: str) -> str | None:
    """What is wrong with a name that may become a file name in the rig's folder (None: nothing): the
    name rule is :data:`NAME_RULE`, so a name can never climb out of the folder (no ``/``, no ``..``, no
    leading ``.``), hide there, or make a socket path longer than AF_UNIX allows."""
    if not name:
        return "is empty"
    if len(name) > NAME_MAX:
        return f"is {len(name)} characters long (at most {NAME_MAX})"
    if _NAME.fullmatch(name) is None:
        bad = sorted({c for c in name if not (c.isascii() and (c.isalnum() or c in "_.@-"))})
        if bad:
            return "has " + " ".join(repr(c) for c in bad) + " in it"
        return f"starts with {name[0]!r}"
    return None


def state_file(folder: Path, name: str, suffix: str = "") -> Path:
    """``folder/NAMEsuffix``: a file a participant creates (or removes) in the rig's folder for a name;
    a ConfigError when ``name`` breaks the name rule or the path (symbolic links resolved) is not a file
    directly inside ``folder``, so no name ever writes or removes a file anywhere else."""
    problem = name_problem(name)
    if problem is not None:
        raise ConfigError(f"name = {name!r} {problem}: names must be {NAME_RULE}")
    path = folder / f"{name}{suffix}"
    if path.resolve().parent != folder.resolve():
        raise ConfigError(f"{path} is not a file inside the rig's folder {folder}; refusing to use it")
    return path


def _num(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else str(value)


def _bound(value: float, hexa: bool) -> str:
    return f"0x{int(value):X}" if hexa and value else _num(value)


def _describe(key: Key) -> str:
    """'must be 1..127', 'must be a number >= 0', 'must be one of ...', 'must be a string'."""
    if key.choices is not None:
        return "must be one of " + ", ".join(repr(c) for c in key.choices)
    lo, hi = key.min, key.max
    word = {int: "", float: "a number ", str: "a non-empty string", bool: "true or false",
            dict: "a table"}.get(key.type, key.type.__name__)
    if key.type in (int, float):
        if lo is not None and hi is not None:
            text = f"must be {word}{_bound(lo, key.hex)}..{_bound(hi, key.hex)}"
        elif lo is not None:
            text = f"must be {word or 'an integer '}>= {_bound(lo, key.hex)}"
        elif hi is not None:
            text = f"must be {word or 'an integer '}<= {_bound(hi, key.hex)}"
        else:
            text = "must be " + ("an integer" if key.type is int else "a number")
    else:
        text = f"must be {word}"
    return text + (f" ({key.help})" if key.help else "")


def section_error(where: str, message: str) -> ConfigError:
    """The one format of a rig-file error: ``FILE [[section]] #n (name): message``, one line."""
    return ConfigError(f"{where}: {message}")


def _check(value: Any, key: Key, path: str, where: str, buses: Sequence[str] | None) -> Any:
    if key.false_is_none and value is False:
        return None
    kind = key.type
    bad = False
    if kind is int:
        bad = isinstance(value, bool) or not isinstance(value, int)
    elif kind is float:
        bad = isinstance(value, bool) or not isinstance(value, int | float)
        if not bad:
            value = float(value)
    elif kind is str:
        bad = not isinstance(value, str) or not value
    elif kind is bool:
        bad = not isinstance(value, bool)
    elif kind is dict:
        if not isinstance(value, Mapping):
            bad = True
        elif key.keys is not None:
            return validate_table(value, key.keys, where, buses, prefix=f"{path}.")
        else:
            return dict(value)
    elif not isinstance(value, kind):
        bad = True
    if not bad and key.choices is not None and value not in key.choices:
        bad = True
    if not bad and kind in (int, float):
        bad = (key.min is not None and value < key.min) or (key.max is not None and value > key.max)
    if bad:
        hexa = key.hex and isinstance(value, int) and not isinstance(value, bool) and value >= 0
        shown = f"0x{value:X}" if hexa else repr(value)
        raise section_error(where, f"{path} {_describe(key)}, got {shown}")
    if key.name:
        problem = name_problem(value)
        if problem is not None:
            raise section_error(where, f"{path} = {value!r} {problem}: names must be {NAME_RULE}")
    if key.bus and buses is not None and value not in buses:
        raise section_error(where, f"{path} = {value!r} names an unknown bus (declared: "
                                   f"{', '.join(buses) or 'none'})")
    return value


def validate_table(raw: Mapping[str, Any], keys: Mapping[str, Key], where: str,
                   buses: Sequence[str] | None = None, prefix: str = "") -> dict[str, Any]:
    """Check a section (or an inline table) against ``keys``; returns it with defaults filled in.

    ``where`` names the file and the section; every error is one :class:`ConfigError` line
    ``where: key problem``. ``buses``: the declared bus names (None: not checked).
    """
    if not isinstance(raw, Mapping):
        raise section_error(where, f"{prefix.rstrip('.') or 'section'} must be a table")
    unknown = sorted(set(raw) - set(keys))
    if unknown:
        table = f"{prefix.rstrip('.')} " if prefix else ""
        raise section_error(where, f"unknown {table}keys {unknown} (allowed: {', '.join(sorted(keys))})")
    out: dict[str, Any] = {}
    for name, key in keys.items():
        path = prefix + name
        if raw.get(name) is not None:  # TOML has no null: None is an already-validated absent key
            out[name] = _check(raw[name], key, path, where, buses)
        elif key.required:
            raise section_error(where, f"{path} is required" + (f" ({key.help})" if key.help else ""))
        elif key.type is dict and key.keys is not None:
            default = key.default if isinstance(key.default, Mapping) else {}
            out[name] = validate_table(default, key.keys, where, buses, prefix=f"{path}.")
        else:
            out[name] = value = key.default
            if key.bus and buses is not None and value is not None and value not in buses:
                raise section_error(where, f"{path} = {value!r} (the default) names an unknown bus (declared: "
                                           f"{', '.join(buses) or 'none'})")
    return out
