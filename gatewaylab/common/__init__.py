"""Shared building blocks below every protocol: the injected clock, the error hierarchy, endpoint
syntax, the parameter store (a device's non-volatile memory) and the server thread. Checksums belong
to their protocols (``od/crc.py``, the devices' codecs)."""

__all__ = []
