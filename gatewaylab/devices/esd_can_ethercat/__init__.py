"""esd CAN-EtherCAT gateway (esd manual C.2922.21 chapter 5): EtherCAT slave of the
Modular Device Profile 5000 with one CAN controller on a virtual bus.

``objects`` (description and dictionary), ``codec`` (process image layouts), ``bitrate`` (0xF800),
``controller`` (the CAN controller side: bit rate, status 0xF108, statistics 0x2010, firmware update,
FoE), ``device`` (:class:`EsdGateway`: the MDP 5000 counter-handshake queues on top of it),
``webmodel`` (the web pages' backend), ``rig`` (the ``esd_can_ethercat`` rig kind); ``web`` is the
HTTP server of chapter 6.
"""

from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway

__all__ = ["EsdGateway", "create_esd_gateway"]
