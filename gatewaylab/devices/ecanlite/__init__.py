"""ECAN-Lite: EtherCAT to 4 x CAN FD gateway (issue 10, docs/devices/ecanlite.md).

``device.EcanLiteDevice`` is the device (slave + MCAN model); ``rig.KIND`` the ``ecanlite`` rig
kind; ``stream`` / ``budget`` the frame-stream codec; ``mcan`` / ``system`` the CAN side and the
maintenance objects; ``host/`` the host library (a later issue).
"""
