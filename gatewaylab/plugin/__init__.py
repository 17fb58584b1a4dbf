"""The device plugin API (docs/devices/writing-a-device.md): what a rig-file kind implements and what it
may use of the rig. Devices inside and outside gatewaylab import these names from here."""

from gatewaylab.plugin.participant import (
    NAME_MAX,
    NAME_RULE,
    CheckedSection,
    DeviceKind,
    Key,
    Participant,
    ParticipantBase,
    RigContext,
    name_problem,
    section_error,
    state_file,
    validate_table,
)

__all__ = ["NAME_MAX", "NAME_RULE", "CheckedSection", "DeviceKind", "Key", "Participant", "ParticipantBase",
           "RigContext", "name_problem", "section_error", "state_file", "validate_table"]
