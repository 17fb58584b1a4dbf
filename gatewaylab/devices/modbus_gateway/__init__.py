"""Modbus TCP to CANopen gateway: CANopen objects of chosen nodes as Modbus registers (issue 14)."""
