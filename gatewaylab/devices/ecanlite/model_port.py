"""What the system objects (``system.py``) call on the device model: a narrow interface.

:class:`~gatewaylab.devices.ecanlite.model.McanModel` owns a
:class:`~gatewaylab.devices.ecanlite.system.SystemModel` and hands it itself; the system objects
see only this Protocol -- the channels, their settings to load and read back, the pin rotation,
the flash and the running firmware -- so ``system.py`` reads (and imports) without the model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

from gatewaylab.common.clock import Clock
from gatewaylab.devices.ecanlite.flash import FlashMedium
from gatewaylab.devices.ecanlite.mcan.channel import McanChannel
from gatewaylab.devices.ecanlite.mcan.filters import FilterElement
from gatewaylab.devices.ecanlite.mcan.layout import ApplyStatus
from gatewaylab.devices.ecanlite.ota import FirmwareVersion

__all__ = ["ModelPort"]


class ModelPort(Protocol):
    """The device model as the system objects use it (0x8000 rotation and reboot, flash save/load,
    factory reset, the FoE update's new firmware, the register service's channels)."""

    clock: Clock
    #: The running firmware; an accepted FoE update sets the new one.
    version: FirmwareVersion

    @property
    def flash(self) -> FlashMedium:
        """The configuration flash and the APP partition."""
        ...

    @property
    def channels(self) -> Sequence[McanChannel]:
        """The four MCAN channels by logical index."""
        ...

    @property
    def version_string(self) -> str:
        """0x100A text of the running firmware."""
        ...

    def rotate(self, rotation: int) -> None:
        """0x8000:12: move logical channel k to pin group (k + rotation) % 4."""
        ...

    def reset(self) -> None:
        """A device reset: the channels restart from the flash image."""
        ...

    def config_values(self, k: int) -> dict[int, int]:
        """The requested 0x800x values of channel ``k``."""
        ...

    def policy_values(self, k: int) -> dict[int, int]:
        """The requested 0x802x values of channel ``k``."""
        ...

    def load_channel_settings(self, k: int, values: Mapping[int, int], std: Sequence[FilterElement] = (),
                              ext: Sequence[FilterElement] = ()) -> ApplyStatus:
        """Settings from flash or the factory defaults become channel ``k``'s configuration, applied."""
        ...

    def load_policy_values(self, k: int, values: Mapping[int, int]) -> int:
        """0x802x values from flash or the defaults become channel ``k``'s policy (0 OK, 1 fail)."""
        ...
