"""The device plugin interface under its public name (docs/devices/writing-a-device.md).

The definitions live in :mod:`gatewaylab.bus.participant`, below every device in the layering, so
the built-in devices use them without importing ``rig``; packages outside gatewaylab import them
from here.
"""

from gatewaylab.bus.participant import DeviceKind, Key, Participant, RigContext, section_error, validate_table

__all__ = ["DeviceKind", "Key", "Participant", "RigContext", "section_error", "validate_table"]
