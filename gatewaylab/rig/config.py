"""Rig files (TOML): the clock mode, the buses and the simulated participants."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from ..common.errors import ConfigError

CLOCK_MODES = ("realtime", "simulated")


@dataclass(frozen=True)
class BusConfig:
    name: str
    bitrate: int = 1_000_000
    data_bitrate: int | None = None
    #: False: frames take no time on the wire (arbitration order still applies).
    timing: bool = True
    #: Cross-process endpoint: "unix" (a socket in the run's state folder), "tcp" (127.0.0.1,
    #: port ``tcp_port``, 0 = any free port) or "none".
    endpoint: str = "unix"
    tcp_port: int = 0


@dataclass(frozen=True)
class RigConfig:
    clock: str = "realtime"
    buses: tuple[BusConfig, ...] = ()
    drives: tuple[dict[str, Any], ...] = ()
    devices: tuple[dict[str, Any], ...] = ()
    ethercat: dict[str, Any] | None = None
    source: str = "<memory>"
    extra: dict[str, Any] = field(default_factory=dict)


_BUS_KEYS = {"name", "bitrate", "data_bitrate", "timing", "endpoint", "tcp_port"}
_TOP_KEYS = {"clock", "bus", "drive", "device", "ethercat", "rig"}


def _bus(raw: dict[str, Any], where: str) -> BusConfig:
    unknown = set(raw) - _BUS_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (allowed: {sorted(_BUS_KEYS)})")
    if "name" not in raw or not isinstance(raw["name"], str):
        raise ConfigError(f"{where}: every [[bus]] needs a name")
    bitrate = raw.get("bitrate", 1_000_000)
    data_bitrate = raw.get("data_bitrate")
    if not isinstance(bitrate, int) or not 10_000 <= bitrate <= 1_000_000:
        raise ConfigError(f"{where}: bitrate {bitrate!r} outside 10 kbit/s .. 1 Mbit/s")
    if data_bitrate is not None and (not isinstance(data_bitrate, int) or not bitrate <= data_bitrate <= 12_000_000):
        raise ConfigError(f"{where}: data_bitrate {data_bitrate!r} must be between bitrate and 12 Mbit/s")
    endpoint = raw.get("endpoint", "unix")
    if endpoint not in ("unix", "tcp", "none"):
        raise ConfigError(f"{where}: endpoint must be 'unix', 'tcp' or 'none'")
    tcp_port = raw.get("tcp_port", 0)
    if not isinstance(tcp_port, int) or isinstance(tcp_port, bool) or not 0 <= tcp_port <= 65535:
        raise ConfigError(f"{where}: tcp_port {tcp_port!r} must be a port number 0..65535")
    return BusConfig(raw["name"], bitrate, data_bitrate, bool(raw.get("timing", True)), endpoint, tcp_port)


def _check_shapes(data: dict[str, Any], source: str) -> None:
    """Tables where the rig file has tables: TOML decodes anything, e.g. ``bus = 3`` or ``rig = "x"``."""
    for key in ("rig", "ethercat"):
        if key in data and not isinstance(data[key], dict):
            raise ConfigError(f"{source}: {key} must be a table ([{key}])")
    for key in ("bus", "drive", "device"):
        if key in data and (not isinstance(data[key], list) or not all(isinstance(e, dict) for e in data[key])):
            raise ConfigError(f"{source}: {key} must be an array of tables ([[{key}]])")


def parse_rig(data: dict[str, Any], source: str = "<memory>") -> RigConfig:
    """Validate a decoded rig file; raises ConfigError naming the offending section."""
    _check_shapes(data, source)
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ConfigError(f"{source}: unknown top-level keys {sorted(unknown)}")
    clock = data.get("clock", data.get("rig", {}).get("clock", "realtime"))
    if clock not in CLOCK_MODES:
        raise ConfigError(f"{source}: clock must be one of {CLOCK_MODES}, not {clock!r}")
    buses = tuple(_bus(b, f"{source} [[bus]] #{i + 1}") for i, b in enumerate(data.get("bus", [])))
    names = [b.name for b in buses]
    if len(set(names)) != len(names):
        raise ConfigError(f"{source}: bus names must be unique, got {names}")
    for section in ("drive", "device"):
        for i, entry in enumerate(data.get(section, [])):
            bus = entry.get("bus")
            if bus is not None and bus not in names:
                raise ConfigError(f"{source} [[{section}]] #{i + 1}: unknown bus {bus!r} (buses: {names})")
            if section == "device" and "kind" not in entry:
                raise ConfigError(f"{source} [[device]] #{i + 1}: needs a kind")
    return RigConfig(clock, buses, tuple(data.get("drive", [])), tuple(data.get("device", [])),
                     data.get("ethercat"), source)


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
