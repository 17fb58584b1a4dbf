"""Web interface of the esd CAN-EtherCAT (manual chapter 6 "Webserver Interface"): the public names.

The device implements :class:`EsdWebBackend` (views :class:`DeviceInfoView`, :class:`CanStatusView`)
and the rig runs one :class:`EsdWebServer` per device::

    server = EsdWebServer(device_backend, clock.lock, port=web_port)
    url = server.start()          # "http://127.0.0.1:PORT/" for the ready file's "web"
    ...
    server.stop()

Pages and their manual sections: :mod:`.web_pages`; HTTP transport: :mod:`.web_server`.
"""

from __future__ import annotations

from gatewaylab.devices.esd_can_ethercat.web_pages import (
    CanStatusView,
    DeviceInfoView,
    EsdWebBackend,
    format_can_status,
)
from gatewaylab.devices.esd_can_ethercat.web_server import DEFAULT_MAX_BODY, EsdWebError, EsdWebServer

__all__ = [
    "DEFAULT_MAX_BODY",
    "CanStatusView",
    "DeviceInfoView",
    "EsdWebBackend",
    "EsdWebError",
    "EsdWebServer",
    "format_can_status",
]
