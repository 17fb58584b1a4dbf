"""maxon IDX: USB command protocol (DLE/STX frames, CRC-CCITT), USB-to-CAN SDO gateway, NMT and LSS.

See docs/devices/maxon_idx.md. ``IdxDevice`` (device.py) is the emulated IDX;
``gatewaylab.hosts.maxon_idx.client.IdxClient`` talks to it (or to real hardware) from a host program.
"""

__all__ = []
