"""Modbus TCP to CANopen gateway: CANopen objects of chosen nodes as Modbus registers (docs/devices/modbus_gateway.md).

``mapping`` (the register map and its codecs), ``device`` (:class:`~.device.ModbusGateway`: register
requests become SDO transfers, sans-I/O), ``server`` (pymodbus's TCP server in its own thread),
``rig`` (the ``modbus_gateway`` rig kind).
"""

__all__ = []
