"""python-can over the EtherCAT gateways: :class:`EthercatHost` hands out a ``can.BusABC``
per gateway CAN channel; ``interfaces`` registers the ``esd_can_ethercat`` python-can interface."""

from gatewaylab.hosts.canhost.channels import EsdChannel
from gatewaylab.hosts.canhost.host import EthercatHost, GatewayBus

__all__ = ["EsdChannel", "EthercatHost", "GatewayBus"]
