"""Which factory builds which rig-file section (imported lazily: a rig pays only for what it uses)."""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module
from typing import Any

from ..common.errors import ConfigError

#: ``[[device]] kind`` -> "module:function"; each function is ``(rig, cfg) -> Participant``.
DEVICE_FACTORIES: dict[str, str] = {
    "maxon_idx": "gatewaylab.devices.maxon_idx.rig:create_device",
    "ethercat_io": "gatewaylab.ethercat.rig:create_io_device",
    "ecanlite": "gatewaylab.devices.ecanlite.rig:create_device",
    "esd_can_ethercat": "gatewaylab.devices.esd_can_ethercat.rig:create_device",
}
DRIVE_FACTORY = "gatewaylab.canopen.rig:create_drive"
SEGMENT_FACTORY = "gatewaylab.ethercat.rig:create_segment"


def resolve(spec: str, what: str) -> Callable[..., Any]:
    module_name, _, attr = spec.partition(":")
    try:
        module = import_module(module_name)
        factory: Callable[..., Any] = getattr(module, attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{what} is not available in this version of gatewaylab ({spec}: {exc})") from None
    return factory
