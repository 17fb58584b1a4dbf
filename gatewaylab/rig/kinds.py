"""Which rig-file kinds exist (the ``gatewaylab.devices`` entry-point group) and the checked build plan.

Built-in devices are registered through the same group as third-party ones (pyproject.toml), so a
package outside this repository adds a ``[[device]] kind`` by declaring an entry point; nothing
in gatewaylab names it. A kind's module is imported only when a rig file uses it.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.plugin import NAME_RULE, DeviceKind, name_problem, section_error

if TYPE_CHECKING:
    from gatewaylab.rig.config import RigConfig

__all__ = ["BUILTIN", "GROUP", "Section", "default_names", "known_kinds", "load", "plan", "registered"]


#: The entry-point group a device package registers its :class:`DeviceKind` objects in.
GROUP = "gatewaylab.devices"
#: Sections of gatewaylab's own that are not devices (``[[bridge]]``, ``[[tunnel]]``): known without an
#: entry point.
BUILTIN = {"bridge": "gatewaylab.rig.bridge:KIND", "tunnel": "gatewaylab.rig.tunnel:KIND"}


def registered() -> dict[str, EntryPoint]:
    """Every installed kind by name (not imported yet)."""
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=GROUP):
        other = found.get(ep.name)
        if other is not None and other.value != ep.value:
            raise ConfigError(f"device kind {ep.name!r} is registered twice ({other.value} and {ep.value}); "
                              f"uninstall one of the packages")
        found[ep.name] = ep
    for name, value in BUILTIN.items():
        found.setdefault(name, EntryPoint(name, value, GROUP))
    return found


def load(name: str, where: str = "", known: Mapping[str, EntryPoint] | None = None) -> DeviceKind:
    """Import one kind; a ConfigError (naming ``where``) when it is not installed or broken."""
    known = registered() if known is None else known
    ep = known.get(name)
    prefix = f"{where}: " if where else ""
    if ep is None:
        hint = ", ".join(sorted(known)) or "none: is gatewaylab installed (pip install -e .)?"
        raise ConfigError(f"{prefix}kind = {name!r} is not installed (known kinds: {hint})")
    try:
        obj = ep.load()
    except Exception as exc:  # a broken plugin is the plugin's bug, reported in one line
        raise ConfigError(f"{prefix}kind {name!r} ({ep.value}) cannot be loaded: {type(exc).__name__}: {exc}") \
            from None
    if not isinstance(obj, DeviceKind):
        raise ConfigError(f"{prefix}kind {name!r}: {ep.value} is a {type(obj).__name__}, not a DeviceKind")
    if obj.kind != name:
        raise ConfigError(f"{prefix}kind {name!r}: {ep.value} calls itself {obj.kind!r}")
    return obj


@dataclass(frozen=True, slots=True)
class Section:
    """One rig-file section, checked: which kind builds it, where it is, its validated keys."""

    kind: DeviceKind
    where: str
    cfg: dict[str, Any]

    @property
    def name(self) -> str | None:
        """The participant's rig-wide name (None for a section that names nothing, such as ``[ethercat]``)."""
        return self.kind.name_of(self.cfg)


def _where(source: str, section: str, index: int | None, raw: Any) -> str:
    text = f"{source} [{section}]" if index is None else f"{source} [[{section}]] #{index + 1}"
    name = raw.get("name") if isinstance(raw, Mapping) else None
    shown = isinstance(name, str) and name_problem(name) is None   # a bad name is quoted by the error itself
    return f"{text} ({name})" if shown else text


def _short(where: str, source: str) -> str:
    return where.removeprefix(f"{source} ")


def plan(config: RigConfig) -> list[Section]:
    """Every participant section of a rig, validated, in build order: ``[[drive]]``, other kinds'
    own arrays, ``[[device]]`` in file order, then single tables such as ``[ethercat]`` (which
    collect the devices built before them). Raises one ConfigError line naming file, section, key."""
    source = config.source
    buses = [b.name for b in config.buses]
    known = registered()
    tables: dict[str, Any] = {"drive": list(config.drives)} if config.drives else {}
    tables.update(config.extra)
    if config.ethercat is not None:
        tables["ethercat"] = config.ethercat
    arrays: list[tuple[str, int | None, Any, DeviceKind]] = []
    singles: list[tuple[str, int | None, Any, DeviceKind]] = []
    for table, value in tables.items():
        kind = load(table, f"{source} [{table}]", known)
        if kind.table != table:
            raise ConfigError(f"{source}: [{table}] is not a section (use [[device]] kind = {table!r})")
        if kind.single:
            if not isinstance(value, Mapping):
                raise ConfigError(f"{source}: [{table}] must be a single table ([{table}], not [[{table}]])")
            singles.append((table, None, value, kind))
        else:
            if not isinstance(value, list):
                raise ConfigError(f"{source}: [[{table}]] must be an array of tables ([[{table}]], not [{table}])")
            arrays.extend((table, i, entry, kind) for i, entry in enumerate(value))
    for i, entry in enumerate(config.devices):
        where = _where(source, "device", i, entry)
        if not isinstance(entry, Mapping) or "kind" not in entry:
            raise section_error(where, "needs a kind (kind = \"...\", the device type)")
        kind_name = entry["kind"]
        if not isinstance(kind_name, str):
            raise section_error(where, f"kind must be a string, got {kind_name!r}")
        kind = load(kind_name, where, known)
        if kind.single:
            raise section_error(where, f"kind = {kind_name!r} is the [{kind.table}] section, not a [[device]]")
        arrays.append(("device", i, entry, kind))

    checked: list[tuple[Mapping[str, Any], DeviceKind, str, dict[str, Any]]] = []
    node_ids: dict[tuple[str, int], str] = {}
    serials: dict[tuple[str, int], str] = {}
    for table, index, raw, kind in [*arrays, *singles]:
        where = _where(source, table, index, raw)
        if not isinstance(raw, Mapping):
            raise section_error(where, "must be a table")
        cfg = kind.validate(raw, where, buses)
        here = _short(where, source)
        if kind.canopen and isinstance(cfg.get("bus"), str):
            bus = cfg["bus"]
            node_id, serial = cfg.get("node_id"), cfg.get("serial")
            if isinstance(node_id, int):
                if (bus, node_id) in node_ids:
                    raise section_error(where, f"node_id = {node_id} is already used on bus {bus!r} by "
                                               f"{node_ids[bus, node_id]} (CANopen node-IDs are unique per bus)")
                node_ids[bus, node_id] = here
            if isinstance(serial, int):
                if (bus, serial) in serials:
                    raise section_error(where, f"serial = 0x{serial:X} is already used on bus {bus!r} by "
                                               f"{serials[bus, serial]} (LSS serial numbers are unique per bus)")
                serials[bus, serial] = here
        checked.append((raw, kind, where, cfg))

    explicit = [not kind.single and isinstance(raw.get("name"), str) for raw, kind, _, _ in checked]
    resolved = default_names([(kind, cfg) if not kind.single and not own else None
                              for (_, kind, _, cfg), own in zip(checked, explicit)],
                             [raw["name"] if own else None for (raw, _, _, _), own in zip(checked, explicit)])
    sections: list[Section] = []
    names: dict[str, str] = {}
    for (raw, kind, where, cfg), default in zip(checked, resolved):
        if default is not None:
            cfg["name"] = default       # the factory builds the participant under its rig-wide name
        section = Section(kind, where, cfg)
        name = section.name
        problem = None if name is None else name_problem(name)
        if problem is not None:         # a default made of other names: a kind's default, a bus name
            raise section_error(where, f"its default name {name!r} {problem}: give it a name = \"...\" "
                                       f"({NAME_RULE})")
        if name is not None and not kind.single:
            if name in names:
                given = "" if isinstance(raw.get("name"), str) else " (the default name)"
                raise section_error(where, f"name = {name!r}{given} is already used by {names[name]} "
                                           f"(every device needs its own name)")
            names[name] = _short(where, source)
        sections.append(section)
    return sections


def default_names(unnamed: Sequence[tuple[DeviceKind, Mapping[str, Any]] | None],
                  given: Sequence[str | None]) -> list[str | None]:
    """The names of the sections that give none, unique in the rig (docs/rig.md "Names").

    ``unnamed[i]`` is the kind and validated keys of a section without ``name`` (None: it has one,
    ``given[i]``, or is a single table). A kind's default (``drive2``, ``idx``) stays as it is
    when no other section has or defaults to it; defaults that meet get their bus appended
    (``drive2@can0``, ``drive2@can1``), and where that is not enough (no bus, or the same bus)
    they are numbered in rig-file order (``ethercat_io1``, ``ethercat_io2``). An explicit name is
    never changed; one that equals a resulting default is refused by the caller.
    """
    plain = [entry[0].name_of(entry[1]) if entry is not None else None for entry in unnamed]
    taken = [name for name in given if name is not None]
    out: list[str | None] = list(plain)
    groups: dict[str, list[int]] = {}
    for i, name in enumerate(plain):
        if name is not None:
            groups.setdefault(name, []).append(i)
    for name, members in groups.items():
        if len(members) == 1 and name not in taken:
            continue
        on_bus: list[str | None] = []
        for i in members:
            entry = unnamed[i]
            assert entry is not None
            kind, cfg = entry
            key = kind.keys.get("bus")
            bus = cfg.get("bus") if key is not None and key.bus else None
            on_bus.append(f"{name}@{bus}" if isinstance(bus, str) else None)
        if None not in on_bus and len(set(on_bus)) == len(on_bus):
            for i, qualified in zip(members, on_bus):
                out[i] = qualified
            continue
        sep = "-" if name[-1:].isdigit() else ""
        numbers = (f"{name}{sep}{n}" for n in itertools.count(1))
        for i in members:
            out[i] = next(c for c in numbers if c not in taken and c not in groups)
    return out


def known_kinds() -> Sequence[str]:
    """The names of every installed kind (for help texts and errors)."""
    return sorted(registered())
