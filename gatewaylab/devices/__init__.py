"""The emulated devices, one package per kind (``canopen_drive``, ``ethercat_io``, ``ethercat_drive``,
``ecanlite``, ``esd_can_ethercat``, ``maxon_idx``, ``modbus_gateway``): each has its model (``device.py``),
its rig kind (``rig.py``, registered as a ``gatewaylab.devices`` entry point) and, where it has one, its
object dictionary (``objects.py``). They build on :mod:`gatewaylab.plugin` and the protocol packages."""

__all__ = []
