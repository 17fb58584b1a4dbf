"""One ECAN-Lite (manual 13, 15.3.1): the MCAN model on up to four bus controllers, the EtherCAT
slave with its application (:class:`~gatewaylab.devices.ecanlite.application.EcanLiteApplication`:
profile objects, state rules, PDO paths) and the device's own life: the FoE OTA update's answer,
the reset that takes it off the line and brings it back in INIT with the new firmware.
Sans-I/O: everything runs on the injected clock.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from gatewaylab.bus.bus import Controller
from gatewaylab.common.clock import Clock
from gatewaylab.devices.ecanlite.application import EcanLiteApplication
from gatewaylab.devices.ecanlite.image import DEVICE_NAME, ecanlite_description
from gatewaylab.devices.ecanlite.model import McanModel
from gatewaylab.ethercat.description import DeviceDescription
from gatewaylab.ethercat.slave import Slave

__all__ = ["ANSWER_WAIT", "RESET_TIME", "EcanLiteApplication", "EcanLiteDevice"]

#: How long the device is gone from the line while it resets after an OTA update (15.3.1).
RESET_TIME = 0.5
#: How long an accepted OTA update waits for the master to read the FoE answer before resetting.
ANSWER_WAIT = 1.0


class EcanLiteDevice:
    """One ECAN-Lite: the MCAN model on up to four controllers, the slave, the OTA reset."""

    def __init__(self, clock: Clock, controllers: Sequence[Controller | None], *, flash_path: Path | None = None,
                 name: str = DEVICE_NAME, serial: int = 0) -> None:
        self.clock = clock
        self.name = name
        self.serial = serial
        self.flash_path = flash_path
        self.controllers = list(controllers)[:4] + [None] * (4 - len(controllers))
        self.resets = 0
        self.on_reset: list[Callable[[EcanLiteDevice], None]] = []
        self.model = McanModel(clock, self.controllers, flash_path, serial=serial)
        self.model.system.on_reboot = self._go_offline  # 0x8000:01 / 0xB000:04 bit 6 restart the device
        self.app = EcanLiteApplication(self)
        self.slave = self._build_slave()

    def _build_slave(self) -> Slave:
        return Slave(self.clock, self._description(), self.app, self.model.ota_handler(self._ota_accepted),
                     name=self.name)

    def _description(self) -> DeviceDescription:
        """The slave's description from the running firmware's objects and version."""
        return ecanlite_description(self.model.object_defs(), serial=self.serial,
                                    software_version=self.model.version_string)

    def _ota_accepted(self) -> None:
        """A good firmware image: answer the FoE transfer, then leave the line and restart (15.3.1)."""
        self.clock.call_soon(self._reset_after_answer, self.clock.now())

    def _reset_after_answer(self, since: float) -> None:
        """The reset waits until the master has read the FoE answer from the mailbox (at most
        :data:`ANSWER_WAIT`): a master that polls the mailbox late still sees its ACK."""
        if self.slave.esc.mailbox_full(1) and self.clock.now() - since < ANSWER_WAIT:
            self.clock.call_later(0.001, self._reset_after_answer, since)
            return
        self._go_offline()

    def _go_offline(self) -> None:
        self.slave.esc.offline = True
        self.slave.esc.power_cycle()
        self.clock.call_later(RESET_TIME, self._come_back)

    def _come_back(self) -> None:
        """Restart: the MCAN model reset (reads the flash, keeps the new version), a fresh dictionary
        and slave state, in INIT. The ESC object stays, as the segment holds it; ``power_cycle``
        cleared it."""
        esc = self.slave.esc
        self.model.reset()  # channels restart from the flash image; the new version stays
        self.app = EcanLiteApplication(self)
        desc = self._description()
        # The firmware starts again behind the same ESC: re-run the slave's construction, keep the ESC.
        Slave.__init__(self.slave, self.clock, desc, self.app, self.model.ota_handler(self._ota_accepted),
                       name=self.name)
        self.slave.esc = esc
        esc.offline = False
        self.resets += 1
        for cb in self.on_reset:
            cb(self)


