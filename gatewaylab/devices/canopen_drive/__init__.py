"""The CANopen CiA 402 servo drive (maxon IDX-like): device, motion plant, homing, rig kind."""

__all__ = []
