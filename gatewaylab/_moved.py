"""Old import paths of modules that moved to their role's room in release 0.2 (issue 22).

``import gatewaylab.canopen.drive`` still works for one release: it returns the module at its new
path (the same module object, so classes and isinstance checks agree) with a DeprecationWarning.
Installed from ``gatewaylab/__init__.py``; remove this file and that line in the release after.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from collections.abc import Sequence
from types import ModuleType

#: old dotted path -> new dotted path
MOVED: dict[str, str] = {
    "gatewaylab.bus.participant": "gatewaylab.plugin.participant",
    "gatewaylab.bus.transport.bridge": "gatewaylab.rig.bridge",
    "gatewaylab.bus.transport.cannelloni": "gatewaylab.rig.tunnel",
    "gatewaylab.bus.transport.send_cli": "gatewaylab.cli.send",
    "gatewaylab.canopen.crc": "gatewaylab.od.crc",
    "gatewaylab.canopen.drive": "gatewaylab.devices.canopen_drive.device",
    "gatewaylab.canopen.homing": "gatewaylab.devices.canopen_drive.homing",
    "gatewaylab.canopen.lesson_cli": "gatewaylab.cli.lesson",
    "gatewaylab.canopen.lessons": "gatewaylab.cli.lessons",
    "gatewaylab.canopen.lss_cli": "gatewaylab.cli.lss",
    "gatewaylab.canopen.monitor_cli": "gatewaylab.cli.monitor",
    "gatewaylab.canopen.plant": "gatewaylab.devices.canopen_drive.plant",
    "gatewaylab.canopen.plot_cli": "gatewaylab.cli.plot",
    "gatewaylab.canopen.rig": "gatewaylab.devices.canopen_drive.rig",
    "gatewaylab.devices.canhost": "gatewaylab.hosts.canhost",
    "gatewaylab.devices.canhost.host": "gatewaylab.hosts.canhost.host",
    "gatewaylab.devices.canhost.plugin": "gatewaylab.hosts.canhost.interfaces",
    "gatewaylab.devices.ecanlite.cli": "gatewaylab.cli.ecan",
    "gatewaylab.devices.ecanlite.host": "gatewaylab.hosts.ecanlite",
    "gatewaylab.devices.ecanlite.host.adapter": "gatewaylab.hosts.ecanlite.adapter",
    "gatewaylab.devices.ecanlite.host.cia402": "gatewaylab.hosts.ecanlite.cia402",
    "gatewaylab.devices.ecanlite.host.cli": "gatewaylab.cli.ecan_programs",
    "gatewaylab.devices.ecanlite.host.demo": "gatewaylab.hosts.ecanlite.demo",
    "gatewaylab.devices.ecanlite.host.port": "gatewaylab.hosts.ecanlite.port",
    "gatewaylab.devices.esd_can_ethercat.host": "gatewaylab.hosts.esd_can_ethercat",
    "gatewaylab.devices.esd_can_ethercat.host.api": "gatewaylab.hosts.esd_can_ethercat.api",
    "gatewaylab.devices.esd_can_ethercat.host.config": "gatewaylab.hosts.esd_can_ethercat.config",
    "gatewaylab.devices.esd_can_ethercat.host.gateway": "gatewaylab.hosts.esd_can_ethercat.gateway",
    "gatewaylab.devices.esd_can_ethercat.host.handshake": "gatewaylab.hosts.esd_can_ethercat.handshake",
    "gatewaylab.devices.esd_can_ethercat.host.loop": "gatewaylab.hosts.esd_can_ethercat.loop",
    "gatewaylab.devices.modbus_gateway.gateway": "gatewaylab.devices.modbus_gateway.device",
    "gatewaylab.devices.maxon_idx.host": "gatewaylab.hosts.maxon_idx",
    "gatewaylab.devices.maxon_idx.host.cli": "gatewaylab.cli.idx",
    "gatewaylab.devices.maxon_idx.host.client": "gatewaylab.hosts.maxon_idx.client",
    "gatewaylab.devices.maxon_idx.host.link": "gatewaylab.hosts.maxon_idx.link",
    "gatewaylab.devices.maxon_idx.host.usb_backend": "gatewaylab.hosts.maxon_idx.usb_backend",
    "gatewaylab.ethercat.backend": "gatewaylab.hosts.ethercat.backend",
    "gatewaylab.ethercat.ec_cli": "gatewaylab.cli.ec",
    "gatewaylab.ethercat.ec_server": "gatewaylab.cli.ec_server",
    "gatewaylab.ethercat.io_device": "gatewaylab.devices.ethercat_io.device",
    "gatewaylab.ethercat.master": "gatewaylab.hosts.ethercat.master",
    "gatewaylab.ethercat.net_cli": "gatewaylab.cli.net",
    "gatewaylab.ethercat.rig": "gatewaylab.rig.segment",
    "gatewaylab.ethercat.wire_backend": "gatewaylab.hosts.ethercat.pysoem_backend",
    "gatewaylab.migrate.cli": "gatewaylab.cli.migrate",
    "gatewaylab.rig.cli": "gatewaylab.cli.main",
    "gatewaylab.rig.demo": "gatewaylab.cli.demo",
    "gatewaylab.rig.ec": "gatewaylab.cli.ec",
    "gatewaylab.rig.ecan": "gatewaylab.cli.ecan",
    "gatewaylab.rig.fault_cli": "gatewaylab.cli.fault",
    "gatewaylab.rig.migrate": "gatewaylab.cli.migrate_rig",
    "gatewaylab.rig.plugin": "gatewaylab.plugin",
}


class MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old path in :data:`MOVED` and loads it as the module at its new path."""

    def find_spec(self, fullname: str, path: Sequence[str] | None = None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        """A spec for an old path (a package where the new path is one), None for every other name."""
        new = MOVED.get(fullname)
        if new is None:
            return None
        found = importlib.util.find_spec(new)
        is_package = found is not None and found.submodule_search_locations is not None
        return importlib.machinery.ModuleSpec(fullname, self, is_package=is_package)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        """The module at the new path (imported now if need be), with a DeprecationWarning."""
        new = MOVED[spec.name]
        # stacklevel 2: the warnings module skips importlib's own frames, so this names the importing line
        warnings.warn(f"{spec.name} moved to {new}; the old path goes in the next release",
                      DeprecationWarning, stacklevel=2)
        module = importlib.import_module(new)
        spec.loader_state = module.__spec__     # importlib writes the old spec into the module next
        return module

    def exec_module(self, module: ModuleType) -> None:
        """Give the module its own spec back: it ran when it was imported at its new path."""
        old = module.__spec__
        if old is not None and old.loader_state is not None:
            module.__spec__ = old.loader_state


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once per interpreter)."""
    if not any(isinstance(f, MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedModuleFinder())
