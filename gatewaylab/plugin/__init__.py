"""The device plugin API (docs/devices/writing-a-device.md): what a rig-file kind implements and what it
may use of the rig. Devices inside and outside gatewaylab import these names from here."""

from gatewaylab.plugin.participant import (
    CheckedSection,
    DeviceKind,
    Key,
    Participant,
    ParticipantBase,
    RigContext,
    section_error,
    validate_table,
)

__all__ = ["CheckedSection", "DeviceKind", "Key", "Participant", "ParticipantBase", "RigContext", "section_error",
           "validate_table"]
