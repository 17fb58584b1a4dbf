"""Which modules are compiled with mypyc, and which of them run compiled in this process.

``COMPILED_MODULES`` is the one list of modules the build compiles: ``setup.py`` reads it from this
file (without importing the package), the runtime checks below read it too. Extend it when a module
joins the hot paths; the module must stay mypyc-compilable (docs/performance.md).

This module imports nothing of gatewaylab at module level: setup.py executes it on its own.
"""

from __future__ import annotations

import os
import warnings
from importlib import import_module
from importlib.machinery import EXTENSION_SUFFIXES, ExtensionFileLoader
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import argparse

__all__ = [
    "COMPILED_MODULES",
    "PACKAGE_DIR",
    "PURE_ENV",
    "compiled_modules",
    "extension_paths",
    "pure_forced",
    "source_path",
    "stale_extensions",
    "summary",
    "version_action",
    "warn_if_stale",
]


#: Modules (files, not packages) compiled by ``pip install .`` / ``make install`` when a C compiler is usable.
COMPILED_MODULES: tuple[str, ...] = (
    "gatewaylab.bus.frame",
    "gatewaylab.bus.bus",
    "gatewaylab.bus.timing",
    "gatewaylab.bus.controller",
    "gatewaylab.bus.stats",
    "gatewaylab.common.clock",
    "gatewaylab.od.types",
    "gatewaylab.od.dictionary",
    # the ESC frame path: every datagram of every cycle runs through these (docs/performance.md)
    "gatewaylab.ethercat.datagram",
    "gatewaylab.ethercat.esc",
    "gatewaylab.ethercat.esc_memory",
    "gatewaylab.ethercat.esc_al",
    "gatewaylab.ethercat.esc_dc",
    "gatewaylab.ethercat.esc_dc_clock",
    "gatewaylab.ethercat.esc_sii",
    "gatewaylab.ethercat.esc_events",
    "gatewaylab.ethercat.esc_registers",
    "gatewaylab.ethercat.slave",
    "gatewaylab.ethercat.segment",
    # the applications behind the ESC in every cycle of a segment: the drives' outputs and control
    # periods, the io box's loop-back (the 1 kHz segment of docs/performance.md)
    "gatewaylab.devices.ethercat_drive.device",
    "gatewaylab.devices.ethercat_io.device",
    "gatewaylab.od.sdo",
    "gatewaylab.canopen.pdo",
    "gatewaylab.canopen.sync",
    # the node's frame path (send of every TPDO) and the node attributes PDO/SYNC/SDO read natively
    "gatewaylab.canopen.node",
    "gatewaylab.canopen.sdo_server",
    "gatewaylab.devices.canopen_drive.device",
    "gatewaylab.devices.canopen_drive.modes",
    "gatewaylab.devices.canopen_drive.plant",
    "gatewaylab.devices.ecanlite.stream.format",
    "gatewaylab.devices.ecanlite.stream.layout",
    "gatewaylab.devices.ecanlite.stream.packets",
    "gatewaylab.devices.ecanlite.stream.encode",
    "gatewaylab.devices.ecanlite.stream.decode",
    "gatewaylab.devices.ecanlite.budget",
    "gatewaylab.devices.esd_can_ethercat.codec",
)

#: Set to anything but "" or "0": every gatewaylab module is imported from its ``.py`` source.
PURE_ENV = "GATEWAYLAB_PURE"

PACKAGE_DIR = Path(__file__).resolve().parent


def pure_forced() -> bool:
    """True when ``GATEWAYLAB_PURE`` asks for pure Python (read by ``gatewaylab/__init__.py``)."""
    return os.environ.get(PURE_ENV, "") not in ("", "0")


def source_path(module: str, package_dir: Path = PACKAGE_DIR) -> Path:
    """The ``.py`` file of a listed module, e.g. ``gatewaylab.bus.bus`` -> ``<package>/bus/bus.py``."""
    return package_dir.joinpath(*module.split(".")[1:]).with_suffix(".py")


def extension_paths(module: str, package_dir: Path = PACKAGE_DIR) -> list[Path]:
    """The compiled extension files (``bus.cpython-311-x86_64-linux-gnu.so``, ...) beside a module's source."""
    stem = source_path(module, package_dir).with_suffix("")
    return [p for suffix in EXTENSION_SUFFIXES if (p := stem.with_name(stem.name + suffix)).exists()]


def compiled_modules() -> list[str]:
    """The listed modules that run compiled in this process (each is imported to find out)."""
    return [name for name in COMPILED_MODULES
            if isinstance(getattr(import_module(name).__spec__, "loader", None), ExtensionFileLoader)]


def summary() -> str:
    """``compiled: bus.frame, bus.bus, ...`` (names below ``gatewaylab.``) or ``pure Python``, for ``--version``."""
    compiled = compiled_modules()
    if not compiled:
        return f"pure Python, {PURE_ENV} set" if pure_forced() else "pure Python"
    return "compiled: " + ", ".join(name.removeprefix("gatewaylab.") for name in compiled)


def stale_extensions(modules: tuple[str, ...] = COMPILED_MODULES, package_dir: Path = PACKAGE_DIR) -> list[str]:
    """Listed modules whose compiled extension is older than their ``.py`` (edited since the build)."""
    stale: list[str] = []
    for name in modules:
        source = source_path(name, package_dir)
        extensions = extension_paths(name, package_dir)
        if source.exists() and any(ext.stat().st_mtime < source.stat().st_mtime for ext in extensions):
            stale.append(name)
    return stale


def warn_if_stale() -> None:
    """In a source checkout (editable install), warn when a compiled module would run older code than its ``.py``.

    Installed wheels are not checked: unpacking may give the ``.py`` a later mtime than the ``.so``.
    """
    if pure_forced() or not (PACKAGE_DIR.parent / "pyproject.toml").exists():
        return
    stale = stale_extensions()
    if stale:
        warnings.warn(f"compiled modules older than their source, running the OLD code: {', '.join(stale)}; "
                      f"rebuild with `make install` (or set {PURE_ENV}=1)", RuntimeWarning, stacklevel=2)


def version_action(version: str) -> type[argparse.Action]:
    """An argparse action for ``--version``: prints ``<version> (<summary()>)`` on one line and exits.

    The summary is found only when asked (it imports the listed modules); argparse's own version
    action would find it at every start and wrap it at the terminal width.
    """
    import argparse

    class VersionAction(argparse.Action):
        """``--version``: no value; prints and exits like argparse's own version action."""

        def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
            super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                             help="show the version and which modules run compiled, then exit")

        def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                     option_string: str | None = None) -> None:
            print(f"{version} ({summary()})")
            parser.exit()

    return VersionAction
