"""Rig files (TOML): the clock mode, the buses and the simulated participants."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.plugin import Key, name_problem, section_error, validate_table
from gatewaylab.rig import kinds

if TYPE_CHECKING:
    from gatewaylab.rig.scenario import Step

__all__ = ["BUS_KEYS", "CLOCK_MODES", "BusConfig", "RigConfig", "load_rig", "parse_rig"]


CLOCK_MODES = ("realtime", "simulated")
#: The name of the rig's control socket in its folder (``gatewaylab-control.sock``): no bus may have it.
CONTROL_SOCKET = "gatewaylab-control"
#: What an empty rig file is told (docs/rig.md "A minimal rig").
MINIMAL_RIG = ('a minimal rig is one bus, the two lines [[bus]] and name = "can0" '
               '(`gatewaylab rig` prints a whole rig with drives to start from)')


@dataclass(frozen=True, slots=True)
class BusConfig:
    """One ``[[bus]]`` section, validated: what the rig builds the virtual bus and its endpoints from."""

    name: str
    bitrate: int = 1_000_000
    data_bitrate: int | None = None
    #: False: frames take no time on the wire (arbitration order still applies).
    timing: bool = True
    #: Cross-process endpoint: "unix" (a socket in the run's state folder), "tcp" (127.0.0.1,
    #: port ``tcp_port``, 0 = any free port) or "none".
    endpoint: str = "unix"
    tcp_port: int = 0
    #: Also serve the bus over the socketcand protocol on 127.0.0.1:``socketcand_port`` (0: any free port).
    socketcand: bool = False
    socketcand_port: int = 0


@dataclass(frozen=True, slots=True)
class RigConfig:
    """A whole rig file, validated (:func:`parse_rig`); participant sections stay raw tables for their kinds."""

    clock: str = "realtime"
    buses: tuple[BusConfig, ...] = ()
    drives: tuple[dict[str, Any], ...] = ()
    devices: tuple[dict[str, Any], ...] = ()
    ethercat: dict[str, Any] | None = None
    source: str = "<memory>"
    #: Top-level sections of other installed kinds (a plugin's own ``[[name]]``), by name.
    extra: dict[str, Any] = field(default_factory=dict)
    #: The ``[[scenario]]`` steps (gatewaylab.rig.scenario), validated; ``gatewaylab run --scenario`` replaces them.
    scenario: tuple[Step, ...] = ()


#: The keys of a ``[[bus]]`` section, checked by the same validator as every device section.
BUS_KEYS: dict[str, Key] = {
    "name": Key(str, required=True, name=True, help="its socket is NAME.sock in the rig's folder"),
    "bitrate": Key(int, 1_000_000, min=10_000, max=1_000_000, help="nominal bit rate in bit/s"),
    "data_bitrate": Key(int, min=10_000, max=12_000_000, help="CAN FD data phase bit rate in bit/s"),
    "timing": Key(bool, True),
    "endpoint": Key(str, "unix", choices=("unix", "tcp", "none")),
    "tcp_port": Key(int, 0, min=0, max=65535, help="0 = any free port"),
    "socketcand": Key(bool, False),
    "socketcand_port": Key(int, 0, min=0, max=65535, help="0 = any free port"),
}
#: Top-level keys every rig file may have; kinds with a section of their own ([[drive]],
#: [ethercat]) add theirs (gatewaylab.rig.kinds).
_TOP_KEYS = {"clock", "bus", "device", "rig", "scenario"}


def _bus(raw: Any, where: str) -> BusConfig:
    values = validate_table(raw, BUS_KEYS, where)
    if values["name"] == CONTROL_SOCKET:
        raise section_error(where, f"name = {CONTROL_SOCKET!r} is taken by the rig's control socket; choose another")
    bitrate, data_bitrate = values["bitrate"], values["data_bitrate"]
    if data_bitrate is not None and data_bitrate < bitrate:
        raise section_error(where, f"data_bitrate {data_bitrate} must be between bitrate ({bitrate}) and 12 Mbit/s")
    return BusConfig(values["name"], bitrate, data_bitrate, values["timing"], values["endpoint"],
                     values["tcp_port"], values["socketcand"], values["socketcand_port"])


def _where(source: str, section: str, index: int, raw: Any) -> str:
    name = raw.get("name") if isinstance(raw, dict) else None
    shown = isinstance(name, str) and name_problem(name) is None   # a bad name is quoted by the error itself
    return f"{source} [[{section}]] #{index + 1}" + (f" ({name})" if shown else "")


def parse_rig(data: dict[str, Any], source: str = "<memory>") -> RigConfig:
    """Validate a decoded rig file completely (every section against its kind's keys, unique
    names, node-IDs and LSS serials per bus); raises one ConfigError line naming file, section, key."""
    extra: dict[str, Any] = {}
    known: dict[str, Any] | None = None
    for key in sorted(set(data) - _TOP_KEYS - {"drive", "ethercat"}):
        known = kinds.registered() if known is None else known
        if key not in known:
            raise ConfigError(f"{source}: unknown top-level keys [{key!r}] (allowed: "
                              f"{', '.join(sorted(_TOP_KEYS | {'drive', 'ethercat'}))})")
        extra[key] = data[key]
    rig_table = data.get("rig", {})
    if not isinstance(rig_table, dict) or set(rig_table) - {"clock"}:
        raise ConfigError(f"{source} [rig]: only clock = ... is allowed here")
    clock = data.get("clock", rig_table.get("clock", "realtime"))
    if clock not in CLOCK_MODES:
        raise ConfigError(f"{source}: clock must be one of {CLOCK_MODES}, not {clock!r}")
    raw_buses = data.get("bus", [])
    if not isinstance(raw_buses, list):
        raise ConfigError(f"{source}: [[bus]] must be an array of tables ([[bus]], not [bus])")
    buses = tuple(_bus(b, _where(source, "bus", i, b)) for i, b in enumerate(raw_buses))
    names: list[str] = []
    for i, b in enumerate(buses):
        if b.name in names:
            raise section_error(_where(source, "bus", i, {"name": b.name}),
                                f"name = {b.name!r} is not unique (bus names must be unique)")
        names.append(b.name)
    for section in ("drive", "device"):
        entries = data.get(section, [])
        if not isinstance(entries, list):
            raise ConfigError(f"{source}: [[{section}]] must be an array of tables ([[{section}]], not [{section}])")
        for i, entry in enumerate(entries):
            where = _where(source, section, i, entry)
            if not isinstance(entry, dict):
                raise section_error(where, "must be a table")
            bus = entry.get("bus")
            if bus is not None and bus not in names:
                raise section_error(where, f"bus = {bus!r} names an unknown bus "
                                           f"(declared: {', '.join(names) or 'none'})")
            if section == "device" and "kind" not in entry:
                raise section_error(where, "needs a kind (kind = \"...\", the device type)")
    scenario: tuple[Step, ...] = ()
    if "scenario" in data:
        from gatewaylab.rig.scenario import parse_scenario  # the fault table: only for a rig with a scenario

        scenario = parse_scenario(data["scenario"], source)
    config = RigConfig(clock, buses, tuple(data.get("drive", [])), tuple(data.get("device", [])),
                       data.get("ethercat"), source, extra, scenario)
    if not (buses or config.drives or config.devices or config.ethercat is not None or extra):
        raise ConfigError(f"{source}: the rig declares nothing to run (no [[bus]], no device); {MINIMAL_RIG}")
    kinds.plan(config)
    return config


def load_rig(path: str | Path | None = None) -> RigConfig:
    """Load a rig file; ``None`` loads the default rig shipped in the package."""
    if path is None:
        text = resources.files("gatewaylab.rig").joinpath("default.toml").read_text()
        source = "default.toml"
    else:
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise ConfigError(f"cannot read rig file {path}: {exc}") from None
        source = str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return parse_rig(data, source)
