"""``ethercat_drive``: a CoE CiA 402 servo drive (1..4 axes, ETG.6010) as an EtherCAT slave.

The axes are the CANopen drive of :mod:`gatewaylab.devices.canopen_drive.device` (state machine, modes, 0x603F
error codes, plant) on the slave's dictionary; see ``docs/devices/ethercat_drive.md``.
"""

from gatewaylab.devices.ethercat_drive.device import (
           AXIS_OFFSET,
           PRODUCT_CODE,
           DriveApplication,
           EthercatDrive,
           create_drive_slave,
           drive_description,
)

__all__ = ["AXIS_OFFSET", "PRODUCT_CODE", "DriveApplication", "EthercatDrive", "create_drive_slave",
           "drive_description"]
