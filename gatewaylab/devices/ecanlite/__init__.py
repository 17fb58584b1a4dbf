"""ECAN-Lite: EtherCAT to 4 x CAN FD gateway (docs/devices/ecanlite.md).

``device.EcanLiteDevice`` is the device (slave + MCAN model); ``rig.KIND`` the ``ecanlite`` rig
kind; ``stream`` / ``budget`` the frame-stream codec; ``mcan`` / ``system`` the CAN side and the
maintenance objects; ``flash`` / ``ota`` the firmware update. The master's side of the device (the
host library) is :mod:`gatewaylab.hosts.ecanlite`.
"""

__all__ = []
