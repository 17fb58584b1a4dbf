"""ECAN-Lite host library: the three layers of the IgH sample package in Python (15.1).

- :mod:`.adapter` -- slaves, PDO multiplier, startup SDOs, DC SYNC0, OP, raw PDO buffers, WKC;
- :mod:`.port` -- the MCAN Port: channel setup, send / schedule / receive, PDO writer and parser;
- :mod:`.cia402` -- CANopen CiA 402 axes in CSP through the Port.
"""

__all__ = []
