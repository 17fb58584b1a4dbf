"""esd CAN-EtherCAT -> ECAN-Lite migration kit: configuration translation and the
``gatewaylab migrate`` command. Depends on the devices, never the reverse."""

__all__ = []
